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

/// The algorithm that turns the result's grid into triangles (`extractor:`).
enum class MeshExtractor {
    MarchingCubes,  ///< marching cubes on the grid's voxels (mesher/extract/MarchingCubes)
    Bcc,            ///< marching tetrahedra on the grid's voxels plus cube centres (BccTetrahedra)
};

/// The words of `extractor:`, in the order of MeshExtractor.
const std::vector<std::string>& meshExtractorNames();
/// The word of @a extractor (`marching-cubes`, `bcc`).
const std::string& meshExtractorName(MeshExtractor extractor);
/// The extractor a word names, or none.
std::optional<MeshExtractor> meshExtractorFromName(const std::string& word);

/// How a mesh is made from the result: the extractor on the recipe's grid, then projection and
/// decimation.
struct MeshOptions {
    /// Marching cubes (the default) or marching tetrahedra on the BCC lattice.
    MeshExtractor extractor = MeshExtractor::MarchingCubes;
    /// Vertices moved onto the true surface (Newton along the field's gradient).
    bool project = false;
    /// Error-bounded decimation: every point of every triangle within this of the true surface
    /// (mm); none: no decimation.
    std::optional<double> tolerance;
    /// With a tolerance: a smooth result is meshed on a coarse grid and refined where it strays
    /// (true), or meshed on a grid fine enough for the tolerance and decimated (false).
    bool refine = true;
    /// With a tolerance: a mesh that strays beyond it fails the job (JobError, exit 3) instead of
    /// the warning `mesh_tolerance`. Not part of what makes two meshes the same.
    bool strict = false;
    /// Where the tolerance was given ("file:line:col" or "--tolerance"), for messages; not part
    /// of what makes two meshes the same.
    std::string toleranceWhere;

    bool operator==(const MeshOptions& o) const
    {
        return extractor == o.extractor && project == o.project && tolerance == o.tolerance && refine == o.refine;
    }
    /// True for the extractor's mesh as it made it (what a bare file name asks for).
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
