/// @file SkinFrame.h
/// @brief Skin-following frames: hexahedral cells between two offset surfaces of a part
/// (IntraLattice's conformal mapping between surfaces, made general for any closed part), and
/// unit cells mapped into them.
#pragma once

#include "engine/frames/StrutFrames.h"
#include "fields/frames/SkinCells.h"

#include <nlohmann/json.hpp>

#include <memory>

namespace voxlat {

/// Where the cells go: between the offset surfaces at depths @a outer and @a inner below the
/// part's surface, @a layers cells deep, about @a size wide along the surface.
struct SkinLayout {
    double outer = 0.0;  ///< depth a of the outer surface (mm, >= 0)
    double inner = 1.0;  ///< depth b of the inner surface (mm, > a)
    int layers = 1;
    double size = 1.0;  ///< cell size along the surface (mm); the quads come out about this wide
    /// Outer cells also claim points out to w = -extension (clipped at depth a): the sliver
    /// between their chord faces and the curved surface. 0 for strut frames.
    double extension = 0.0;
};

/// What building the cells found, for the report and the tests.
struct SkinCellStats {
    std::size_t quads = 0;     ///< quads of the outer surface
    std::size_t vertices = 0;  ///< their corners
    std::size_t hexes = 0;     ///< cells kept (quads x layers, less the dropped)
    /// Cells dropped: a corner that could not reach its depth (the part is thinner there than
    /// twice the inner depth) or a cell turned inside out (its Jacobian not positive at a corner).
    std::size_t dropped = 0;
    std::size_t unreached = 0;  ///< of the dropped: a corner did not reach its depth
    /// Quad edges where the (u, v) axes of the two cells are turned against each other (no
    /// consistent choice exists round irregular vertices); shared faces there are seams.
    std::size_t seamEdges = 0;
    double deepest = 0.0;  ///< the deepest sample of the part's distance on the sampling grid (mm)

    nlohmann::json json() const;
};

/// Builds the cells of @a layout in the part whose signed distance is @a distance (negative
/// inside; a `mesh` part's exact distance grid, or any field whose value is a distance),
/// searching @a region (a box holding the part).
///
/// The outer surface is contoured as quads: the distance (plus the depth a) is sampled on a grid
/// of spacing `size`, and openvdb::tools::volumeToMesh (dual contouring, all quads) gives a closed
/// quad mesh; each vertex is moved onto the exact offset surface (Newton along the gradient),
/// then inward along the gradient, in steps of at most a quarter cell, onto the offset surface of
/// each layer (Newton again). Quad (u, v) axes are turned by a breadth-first walk so neighbours
/// agree wherever they can, and winding is chosen so (u, v, w) is right-handed with w inward.
/// Every corner of a kept cell lies on its offset surface to 1e-5 of the cell size (of the
/// distance given: a mesh's trilinear grid is itself within about half a voxel of the mesh).
///
/// Throws InputError (the message names no location: the caller adds it) when inner <= outer,
/// when the part has no interior at depth a, or when no cell survives at depth b.
std::shared_ptr<const SkinCells> buildSkinCells(const FieldPtr& distance, const Box3& region, const SkinLayout& layout,
                                                SkinCellStats& stats);

/// @a cell mapped into every cell by its trilinear map (cell x, y along the surface, z inward);
/// nodes and struts shared by neighbouring cells appear once.
Frame skinFrame(const UnitCell& cell, const SkinCells& cells);

/// True when the cell's nodes on its side faces (x or y = 0 or 1) are the same after a quarter
/// turn about z: then struts meet across seams too (grid, bcc, fcc, octet, ... are).
bool quarterTurnSymmetric(const UnitCell& cell);

}  // namespace voxlat
