/// @file Job.h
/// @brief One recipe taken through the stages: build fields, solve levels, evaluate, mesh, write.
#pragma once

#include "engine/checks/Pieces.h"
#include "engine/core/Domain.h"
#include "engine/core/JobContext.h"
#include "engine/core/SparseEvaluator.h"
#include "engine/jobs/ReportPage.h"
#include "engine/recipe/FieldBuilder.h"
#include "engine/recipe/MeshSettings.h"
#include "engine/recipe/Recipe.h"
#include "mesher/clip/BoxClip.h"
#include "mesher/extract/TriangleMesh.h"
#include "mesher/tolerance/AdaptiveRefinement.h"
#include "mesher/tolerance/SurfaceProjection.h"
#include "mesher/writers/FrameWriters.h"
#include "mesher/writers/MeshWriters.h"

#include <openvdb/openvdb.h>
#include <map>
#include <nlohmann/json.hpp>

#include <array>
#include <filesystem>
#include <optional>

namespace voxlat {

class GridValueMemo;

/// Runs a recipe stage by stage; each stage runs once, on first need, and records its time in
/// the report. Every file it writes appears whole or not at all.
class Job {
public:
    /// @a context receives progress and warnings and may cancel the job; it must outlive the
    /// job. Without one the job is silent (warnings still land in report.json).
    explicit Job(Recipe recipe, JobContext* context = nullptr);

    JobContext& context() const { return *mContext; }

    const Recipe& recipe() const { return mRecipe; }
    const Domain& domain() const { return mDomain; }

    /// Solves every `density:` level (in dependency order). Idempotent.
    void solveLevels();
    /// A named field, with its levels solved.
    FieldPtr field(const std::string& name);
    /// The sparse grid of the result clipped to the domain (negative inside), evaluated once (and
    /// again if a tolerance mesh freed it, see setGridReleasable()).
    const openvdb::FloatGrid& grid();
    /// Estimates the result's volume without evaluating the recipe's grid when the domain has more
    /// than @a maxVoxels voxels: from maxVoxels / 16 random points, one in each cell of a grid over
    /// the domain's box (sampleVolume()), and `report.json`'s `result` says so (`estimated`: the
    /// method, the points, the standard error). Smaller domains take grid() (exact count, pieces).
    /// Returns whether the volume was estimated.
    bool measureVolume(std::uint64_t maxVoxels);
    /// Whether a tolerance mesh made on a coarser grid may go without the recipe's grid once its
    /// pieces are counted (nothing after it reads the grid): it keeps only the solid's bits while
    /// the leaves are evaluated, or frees a grid made before (W9's peak 515 -> 380 MB freed, 230 MB
    /// with the bits only). writeOutputs() decides it per output from the outputs after it;
    /// `voxlat mesh` sets it.
    void setGridReleasable(bool releasable) { mGridReleasable = releasable; }
    /// Whether the recipe's grid is held now (made and not freed).
    bool holdsGrid() const { return bool(mGrid); }
    /// The watertight mesh of the grid (marching cubes), built once.
    const TriangleMesh& mesh() { return mesh(MeshOptions{}); }
    /// The mesh made with @a options, built once per options: marching cubes on the grid, then
    /// (options.project) every vertex moved onto the true surface, then (options.tolerance)
    /// decimated while every point stays within the tolerance of it. The true surface is the
    /// zero level of surfaceField().
    const TriangleMesh& mesh(const MeshOptions& options);
    /// The field the grid samples: the result clipped to the domain box (negative inside).
    FieldPtr surfaceField();
    /// The first-order signed distance to the surface of surfaceField()'s solid in mm: the largest
    /// of f / |grad f| over the operands of the result's outermost sharp intersection (or the
    /// result) and the domain box (fields/shapes/SurfaceDistance). Decimation and the mesh report
    /// measure with it.
    FieldPtr distanceField();

    /// Writes the recipe's outputs (paths relative to @a outDir) and report.json.
    /// With @a preview, also a picture of the first mesh (NAME.preview.png); with @a html, the
    /// page report.html (ReportPage.h) beside report.json (`voxlat run` and Python ask for it).
    void writeOutputs(const std::filesystem::path& outDir, bool preview = true, bool html = false);
    /// A small mesh of the result for report.html: the first mesh made, clustered
    /// (clusterDecimate), else the result meshed on a coarse grid of the domain.
    TriangleMesh pageMesh();
    /// The values that colour report.html's mesh, where the recipe grades walls.
    std::optional<PageColouring> pageColouring(const TriangleMesh& mesh);
    /// Writes only the mesh made with @a options, to @a path.
    void writeMesh(const std::filesystem::path& path, const MeshOptions& options = {});
    /// Writes the raw marching-cubes mesh to the binary STL @a path as it is made, without ever
    /// holding it (marchingCubesStreamed()): for an output that is the mesh's only use. The same
    /// bytes as writeMesh(path) with default options; the report gets the same `mesh` entry.
    void writeStlWhileMeshing(const std::filesystem::path& path);
    void writeReport(const std::filesystem::path& path);
    /// Writes a shaded PNG picture of the mesh made with @a options (front-right-top view).
    void writePreview(const std::filesystem::path& path, const MeshOptions& options = {});
    /// Slices the result for a resin printer into @a path with @a settings (a `slices:` entry,
    /// parsed when the recipe loaded). Builds no grid and no mesh: every pixel is decided from the
    /// field (engine/SliceJob). With @a pageLayers the layers are also kept small for report.html's
    /// layer view (the first such output's).
    void writeSlices(const SliceSettings& settings, const std::filesystem::path& path, bool pageLayers = false);

    /// The effective stiffness and conductivity of one periodic cell of the result
    /// (engine/jobs/PropertiesJob), computed once; also report.json's `properties`.
    const nlohmann::json& properties();
    /// Writes properties() to @a path (.json) and the directional Young's modulus picture next to it (.png).
    void writeProperties(const std::filesystem::path& path);

    /// Every strut frame of the recipe (in build order, one node list): nodes, struts and the
    /// radius at each strut end at the solved level (solves the levels first).
    BeamFrame frame();
    /// Writes frame() to @a path (.csv, .obj or .3mf, mesher/writers/FrameWriters).
    void writeFrameFile(const std::filesystem::path& path);

    /// Levels, densities, counts, timings and peak memory so far.
    nlohmann::json report() const;

private:
    /// Warns (`stale_temporary`) about temporaries a killed run left beside @a paths.
    void warnStaleTemporaries(const std::vector<std::filesystem::path>& paths) const;
    /// What the output files check between chunks: the context's cancel (throws Cancelled).
    WriteInterrupter writeInterrupter() const
    {
        return [context = mContext] { context->checkCancelled(); };
    }
    /// Evaluates the recipe's grid and puts its volume and pieces into the report (once). With
    /// @a keep false, for a job that only needs those (a tolerance mesh made on a coarser grid with
    /// nothing after it reading the grid), only the solid's bits are kept, 64 bytes a leaf instead
    /// of 2 KB (W9: 265 MB of grid never written). Kept grids go into mGrid.
    void evaluateRecipeGrid(bool keep);
    /// Counts the pieces of the solid @a blocks (solidBlocks()) into the report; more than one is a
    /// warning with the numbers and the fix, unless the recipe says `allow: [pieces]` (a plate of
    /// separate parts).
    void checkPieces(const std::vector<SolidBlock>& blocks);
    /// Once the first mesh is written: each solved lattice's share of its region measured from the
    /// mesh's volume (`density_from_mesh`), and a warning with the numbers and a voxel that closes
    /// the gap when it is more than 1 % from the target. Lattices whose share the mesh cannot give
    /// (a result other than the lattice or its infill, a density box that is not the domain's, a
    /// blended or skin-framed infill) are left out.
    void checkDensityFromMesh();
    /// A solved lattice's share of its region as a mesh of @a meshVolume mm³ holds it, and the
    /// region's words; nullopt for a lattice whose share the mesh of the result cannot give.
    struct MeshShareMeasure {
        double measured = 0.0;
        std::string region;
    };
    std::optional<MeshShareMeasure> meshShareOf(const LevelNode& node, double meshVolume);
    /// Before the first mesh (made with @a options) is made: the one solved lattice's share as
    /// that mesh will hold it, measured from the recipe's grid at the solved level: a raw
    /// marching-cubes mesh's (marchingCubesVolume()); a projected one's as that mesh's with its
    /// vertices moved onto the surface (projectedVolume(), sampled on large grids); a BCC one's
    /// from the BCC mesh of the grid. More than kMeshAimTolerance off its target, the level is
    /// moved by the solve's slope (the finished mesh's offset from marching cubes' kept) so the
    /// mesh holds the target, and the grid is evaluated again (`mesh_aim` in report.json). Else
    /// the grid is kept for the outputs. Once.
    ///
    /// With @a streamTo (the first mesh is a raw marching-cubes STL whose mesh nothing else uses,
    /// written as it is made: writeStlWhileMeshing()), that file is written as the share is
    /// measured, from the same triangles: at a level that stays, the output is then already
    /// written (mStreamedAim) and the grid is meshed once, not twice; a file at a level that
    /// moves is withdrawn from the open OutputTransaction and written again.
    void aimLevelsAtMesh(const MeshOptions& options, const std::filesystem::path* streamTo = nullptr);
    /// The binary STL of the grid @a g's marching-cubes mesh written to @a path as it is made,
    /// timed and with progress under the output's name.
    StreamedStl streamStl(const openvdb::FloatGrid& g, const std::filesystem::path& path);
    /// An STL aimLevelsAtMesh() wrote at the final level, taken by writeStlWhileMeshing().
    struct StreamedAim {
        std::filesystem::path path;
        StreamedStl made;
        std::string stage;  ///< the aim's stage it measured
    };
    std::optional<StreamedAim> mStreamedAim;
    /// The first slices output's layers kept small, for report.html's layer view.
    std::optional<LayerThumbnails> mPageLayers;
    /// A projected mesh @a m of a result with creases (or cut by the domain box without the box
    /// cut) made sharp: crease vertices onto both surfaces, edges across split, straying triangles
    /// refined (CreaseSplit, CreaseRefinement); their counts into @a report.
    void sharpenMeshCreases(TriangleMesh& m, const MeshOptions& options, double meshVoxel, const ProjectionOptions& po,
                            nlohmann::json& report);
    /// The recipe's grid as evaluateRecipeGrid() evaluates it (clipped to the domain), with the
    /// evaluator's counts in @a stats; @a leafVisitor, when set, takes each leaf instead of the grid.
    openvdb::FloatGrid::Ptr evaluateResult(SparseStats& stats,
                                           std::function<void(const openvdb::Coord&, const float*)> leafVisitor = {});
    /// `drain:` under a `slices:` output: the result wrapped in drain channels (planned with the
    /// other drains after the levels are solved), so every output of the run has them.
    void drainForSlices();
    /// A sheet of a constant `thickness:`: its walls measured over one cell into @a entry
    /// (`walls_measured`), and a warning with the numbers when they miss the thickness.
    void checkSheetWalls(const LevelNode& node, nlohmann::json& entry);
    /// @a node's thinnest strut or wall at @a level in @a entry, and the `sub_voxel_features`
    /// warning it calls for (replacing the one told at an earlier level of the same field).
    void reportThinnest(const LevelNode& node, double level, nlohmann::json& entry);

    template <typename Fn>
    auto timed(const std::string& stage, Fn&& fn);

    std::unique_ptr<JobContext> mOwnContext;  ///< the context when the caller gave none
    JobContext* mContext;
    Recipe mRecipe;
    FieldBuilder mBuilder;
    Domain mDomain;
    FieldPtr mResult;
    bool mSolved = false;
    openvdb::FloatGrid::Ptr mGrid;
    bool mGridReleasable = false;
    FieldPtr mSurfaceField, mDistanceField;

    /// One mesh the job made, with what report.json says about it.
    struct MeshVariant {
        MeshOptions options;
        std::unique_ptr<TriangleMesh> mesh;
        nlohmann::json report;  ///< triangles, vertices, projection, decimation, deviation
        /// Volume and area: from the STL writer when it wrote the mesh, else measured when the
        /// report is made.
        mutable std::optional<TriangleMesh::Measures> measures;
        std::vector<std::string> files;
    };
    /// A mesh that strays @a strayMm beyond its tolerance: the warning's message (the numbers and a
    /// voxel and a tolerance that meet it) and report.json's figures.
    struct MeshToleranceMiss {
        std::string message;
        nlohmann::json details;
    };
    MeshToleranceMiss toleranceMiss(double strayMm, const MeshOptions& options) const;
    /// The mesh made with @a options, made on first use (marching cubes, projection, decimation).
    MeshVariant& variant(const MeshOptions& options);
    /// For a tolerance mesh (marching cubes, projected): the mesh extracted from a grid k times
    /// coarser than the recipe's, evaluated from surfaceField(), with its vertices projected
    /// (@a projection), when a k > 1 keeps the pieces, the smallest known feature (at least three
    /// coarse voxels) and a chord error within the tolerance; else null. What was chosen and why
    /// goes into @a extraction; @a voxel is set to the voxel the mesh was extracted at; a refined
    /// mesh's topology (checked with its crossings) goes into @a topology.
    std::unique_ptr<TriangleMesh> coarseMesh(const MeshOptions& options, nlohmann::json& extraction, double& voxel,
                                             ProjectionStats& projection, std::optional<BoxClipStats>& boxCut,
                                             std::optional<MeshTopology>& topology);
    /// The chord error (as coarseMesh() measures it) of the result meshed at voxel @a h and
    /// projected, in a probe box of 32 such voxels at the domain's centre on the full coarse grid
    /// (its inner triangles are the full mesh's); nullopt when such a box
    /// would hold more than an eighth of the domain (the full trial is as cheap). The error in a
    /// part of the mesh is at most the whole mesh's: a probe above the tolerance rejects @a h
    /// without meshing the whole domain at it.
    std::optional<double> probeChordError(double h);
    /// Refines @a mesh (meshed at voxel @a h, projected and cut) until each triangle stays within
    /// 0.9 of @a tolerance of the result (refineToTolerance()).
    AdaptiveRefinementStats refineCoarseMesh(TriangleMesh& mesh, double h, double tolerance);
    /// Whether the result's surface is one smooth field (no sharp boolean operands): its only
    /// creases are where it meets the domain box, which clippedMesh() makes exact.
    bool smoothResult();
    /// The result meshed unclipped on a grid of voxel @a h (two voxels past the domain box),
    /// projected onto its surface (@a projection), then cut by the domain box's faces and capped
    /// (@a boxCut); null when the cut could not be closed (boxCut->failure says why). Without
    /// @a checkCut, the capped mesh's topology is left to the caller to check (boxCut->topology
    /// is empty).
    /// The result on a grid of voxel @a h from the domain box's corner, covering the box and two
    /// voxels past it, unclipped (what a mesh cut by the box's faces, or its estimate, starts from).
    openvdb::FloatGrid::Ptr evaluatePastTheBox(double h);
    /// Newton projection for vertices of a grid of voxel @a h: at most half a voxel, converged
    /// to 1e-4 of the recipe's voxel; moves that make triangles cross held back once a mesh of
    /// this job was found crossing (mCrossingsUnheld).
    ProjectionOptions projectionAt(double h) const
    {
        ProjectionOptions po;
        po.maxMove = 0.5 * h;
        po.tolerance = 1e-4 * mDomain.voxel;
        po.holdBackCrossings = mCrossingsUnheld.has_value();
        return po;
    }
    /// The crossing pairs of the first projected mesh found crossing, made without holding the
    /// projection's crossing moves back (that check costs several times the projection, so it
    /// runs only once a mesh needs it; variant() then makes that mesh again).
    std::optional<std::size_t> mCrossingsUnheld;
    std::unique_ptr<TriangleMesh> clippedMesh(double h, ProjectionStats& projection,
                                              std::optional<BoxClipStats>& boxCut, bool checkCut = true);
    /// Refuses (InputError, naming where the tolerance was given) a mesh tolerance of half the
    /// thinnest strut a node knows or more; warns when it exceeds the voxel.
    void checkTolerance(const MeshOptions& options);
    /// The metadata a 3MF output carries: the recipe's hash, the canonical recipe, the version.
    MeshMetadata meshMetadata() const;
    /// In the order first asked for: report.json's `mesh` describes the first, `meshes` lists
    /// all when there are several.
    std::vector<std::unique_ptr<MeshVariant>> mMeshes;
    nlohmann::json mReport;
    /// What `stiffness:` and `optimize:` found, by field name (merged into report.json `fields`).
    nlohmann::json mDesign = nlohmann::json::object();
    /// The volume (mm³) of the region each solved lattice's density is measured on, by name.
    std::map<std::string, double> mDensityRegionMm3;
    /// checkDensityFromMesh()'s findings, by field name (merged into report.json `fields`).
    nlohmann::json mDensityFromMesh = nlohmann::json::object();
    bool mDensityChecked = false;
    /// Each density solve's level of the indicator, its slope and its achieved share, by name.
    struct SolvedDensity {
        double indicatorLevel = 0.0;
        double slope = 0.0;
        double achieved = 0.0;
        /// Measured on the job's own voxels (the domain, or a mask of it, at the job's voxel; not
        /// a period's pieces at another voxel, a coarse trial or a box that leaves voxels out):
        /// what the mesh's share is predicted from (estimateMeshOffset()).
        bool onJobVoxels = false;
        bool coverage = false;  ///< measured with sub-voxel coverage, not a count
    };
    std::map<std::string, SolvedDensity> mSolvedDensity;
    bool mMeshAimed = false;
    /// Set by aimLevelsAtMesh() around its solveLevels(): a density solve on the recipe's own
    /// lattice then keeps its raw field's leaf values (GridValueMemo) for the grid evaluated next.
    bool mKeepSolvedValues = false;
    /// The memos a solve switched on (mKeepSolvedValues), freed by releaseSolvedValues() after the
    /// next evaluation of the result, or by the aim that takes them over.
    std::vector<const GridValueMemo*> mSolvedValues;
    /// Leaves per stack along z in the result's evaluations on the job's domain (SparseOptions::
    /// stackLeaves): the largest its level nodes ask for (LevelNode::stackLeaves), set by
    /// solveLevels(); a solve on the recipe's lattice uses the same stacks, so the grid asks its
    /// memo for the batches the solve made.
    int mStackLeaves = 1;
    void releaseSolvedValues();
    /// aimLevelsAtMesh()'s grid at the final level and its counts, taken by evaluateRecipeGrid().
    openvdb::FloatGrid::Ptr mAimGrid;
    SparseStats mAimStats;
    /// The raw marching-cubes mesh of the grid at the final level, made by aimLevelsAtMesh()'s
    /// measure, taken by variant() for the first mesh made from that grid.
    std::unique_ptr<TriangleMesh> mAimMesh;
    std::array<std::array<double, 6>, 6> mPropertiesStiffness{};
    /// properties() of a box frame too small to hold a whole repeating cell (@a zone): the frame's
    /// cell homogenized in a frame of enough of them; false when the frame is not a box frame.
    bool unitCellProperties(const RepeatZone& zone);
    /// Writes properties() as a CalculiX/Abaqus material card (`properties: {export}`).
    void writeMaterialCard(const std::filesystem::path& path);
    /// The material cards of a graded lattice (the result, a GradedNode): one per slab of its
    /// grading (one cell thick along its axis), each the cell homogenized at the slab's mean target
    /// density; refused (InputError) when the density also varies across the slabs.
    std::string gradedMaterialCards(const GradedNode& node);
    nlohmann::json mTimings = nlohmann::json::object();
};

}  // namespace voxlat
