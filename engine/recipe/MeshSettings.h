/// @file MeshSettings.h
/// @brief A `mesh:` output entry: its file and how the mesh is made (projection, tolerance).
#pragma once

#include "engine/recipe/KeySpec.h"
#include "engine/recipe/RecipeNode.h"

#include <optional>
#include <string>
#include <vector>

namespace voxlat {

/// The keys of a `mesh:` output written as a map, with their schemas, defaults and meanings.
const std::vector<KeySpec>& meshKeys();

/// How a mesh is made from the result, beyond marching cubes on the recipe's grid.
struct MeshOptions {
    /// Vertices moved onto the true surface (Newton along the field's gradient).
    bool project = false;
    /// Error-bounded decimation: every point of every triangle within this of the true surface
    /// (mm); none: no decimation.
    std::optional<double> tolerance;
    /// Where the tolerance was given ("file:line:col" or "--tolerance"), for messages; not part
    /// of what makes two meshes the same.
    std::string toleranceWhere;

    bool operator==(const MeshOptions& o) const { return project == o.project && tolerance == o.tolerance; }
    /// True for plain marching cubes (what a bare file name asks for).
    bool raw() const { return !project && !tolerance; }
};

/// One `mesh:` output: a file name (`part.stl`) or a map (`{file: part.stl, tolerance: 0.01}`).
struct MeshSettings {
    std::string file;
    MeshOptions options;
};

/// Reads a `mesh:` entry, a file name or a map (errors name file, line and key); checks the
/// file name (checkOutputName) and the values.
MeshSettings parseMeshSettings(const RecipeNode& spec);

/// Checks a tolerance given anywhere (recipe or command line): a positive number of mm. Throws
/// InputError naming @a where.
double checkMeshTolerance(double tolerance, const std::string& where);

}  // namespace voxlat
