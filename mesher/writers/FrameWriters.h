/// @file FrameWriters.h
/// @brief Strut frames (nodes, struts, radii at each end) to files: CSV, OBJ lines, and the 3MF
/// Beam Lattice extension through lib3mf; and a 3MF beam-lattice reader for tests.
#pragma once

#include "fields/core/FieldNode.h"

#include <array>
#include <string>
#include <utility>
#include <vector>

namespace voxlat {

/// A strut frame as beam tools see it: nodes, struts (node index pairs) and the radius at each
/// end of each strut (mm).
struct BeamFrame {
    std::vector<Vec3d> nodes;
    std::vector<std::array<int, 2>> struts;
    std::vector<std::array<double, 2>> radii;  ///< per strut: at nodes[struts[j][0]], at nodes[struts[j][1]]
};

/// Writes @a frame in the format named by the (case-insensitive) extension of @a path:
/// - .csv: the header `x1,y1,z1,x2,y2,z2,r1,r2`, then one row per strut (17 significant digits,
///   so the numbers read back exactly);
/// - .obj: `v x y z` per node, `l i j` per strut (1-based), radii as `# r1 r2` comments after
///   each line element;
/// - .3mf: one mesh object with the nodes as vertices, no triangles, and a beam lattice
///   (lib3mf 1.8; unit millimetre; each beam's two radii, sphere caps; @a metadata as the model's
///   metadata).
/// Throws std::invalid_argument for another extension or bad indices, std::runtime_error on I/O
/// failure. No partial file is ever left at @a path.
void writeFrame(const BeamFrame& frame, const std::string& path,
                const std::vector<std::pair<std::string, std::string>>& metadata = {});

/// Reads the beam lattice of the first mesh object of a 3MF file through lib3mf (nodes are the
/// object's vertices, in single precision as 3MF stores them). Throws std::runtime_error.
BeamFrame readBeamLattice3mf(const std::string& path);

}  // namespace voxlat
