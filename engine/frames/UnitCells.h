/// @file UnitCells.h
/// @brief Strut unit cells (IntraLattice's model): nodes in the unit cube and the struts
/// between them; presets, cells from lines, and the validity rule.
#pragma once

#include "fields/core/FieldNode.h"

#include <array>
#include <string>
#include <utility>
#include <vector>

namespace voxlat {

/// Nodes in [0, 1]^3 and struts as node index pairs (i < j), unique.
struct UnitCell {
    std::string name;
    std::vector<Vec3d> nodes;
    std::vector<std::array<int, 2>> struts;
};

/// A line given by the user, with where it came from (for messages).
struct CellLine {
    Vec3d a{0.0}, b{0.0};
    std::string where;  ///< "file:line" or recipe location
};

/// The preset names, in the order of the recipe docs.
std::vector<std::string> unitCellPresetNames();
/// The preset @a name (throws std::invalid_argument for an unknown name).
UnitCell presetUnitCell(const std::string& name);

/// Builds a cell from lines (IntraLattice's UnitCell constructor): lines that cross or touch
/// another line's interior are split there into nodes, duplicates are dropped, and the cell is
/// scaled to the unit cube and moved to the origin. Throws InputError naming the line for a
/// zero-length line, and for a cell that is flat along an axis.
UnitCell unitCellFromLines(const std::vector<CellLine>& lines, const std::string& name);

/// Reads the `l` elements (with their `v` vertices) of an OBJ file as lines; polylines become
/// consecutive lines. Throws InputError with "file:line: ..." for bad or dangling indices.
std::vector<CellLine> readObjLines(const std::string& path);

/// One OBJ `l` element: its vertices in order and "file:line".
struct ObjPolyline {
    std::vector<Vec3d> points;
    std::string where;
};
/// The `l` elements of an OBJ file as polylines (at least two vertices each), in file order.
/// Throws InputError naming file and line for bad vertices and indices, or when there is none.
std::vector<ObjPolyline> readObjPolylines(const std::string& path);

/// The problems that make a cell invalid for tiling: a face without nodes, a node on a face
/// without its mirror node on the opposite face. Empty for a valid cell.
std::vector<std::string> unitCellProblems(const UnitCell& cell);

}  // namespace voxlat
