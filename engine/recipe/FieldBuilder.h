/// @file FieldBuilder.h
/// @brief Turns a recipe's `fields:` map into a graph of field nodes.
#pragma once

#include "engine/core/Errors.h"
#include "engine/core/JobContext.h"
#include "engine/recipe/KeySpec.h"
#include "engine/recipe/Recipe.h"
#include "fields/levels/LevelSolid.h"
#include "fields/shapes/DrainChannels.h"

#include <nlohmann/json.hpp>

#include <array>
#include <functional>
#include <map>
#include <optional>
#include <set>

namespace voxlat {

/// A node whose level is either fixed or solved for a target density.
struct LevelNode {
    std::string name;
    std::string description;  ///< e.g. "gyroid network"
    std::shared_ptr<LevelSolid> solid;
    std::optional<double> density{};  ///< target relative density
    /// Where the density is measured: the domain unless a node narrows it (a strut lattice
    /// measures over its frame's bounding box).
    std::optional<Box3> densityBox{};
    /// Where the density is measured when the solid fills a part: the voxels with mask < 0 (the
    /// space inside an infill's skin); see solveDensity().
    FieldPtr densityMask{};
    std::string densityOf{};  ///< what the mask is, for the report ("inside the skin of `part`")
    /// Where a lattice laid out in cells of its own exists (a skin frame's cells, negative
    /// inside); its density is measured there (and an infill intersects it with its core).
    FieldPtr region{};
    /// Called with the solved level after a density solve, and again with the level moved for the
    /// mesh (checks and notes that need it: their warnings by JobContext::warnAgain).
    std::function<void(double level)> onSolved{};
    /// The diameter (mm) of the thinnest strut (or wall) the solid has at a level, where the node
    /// knows it: the job warns before evaluating when it is below two voxels.
    std::function<double(double level)> thinnest{};
    /// What thinnest() measures: "strut" (a diameter) or "wall" (a sheet's thickness).
    std::string thinnestKind = "strut";
    /// Measure the density with sub-voxel coverage rather than by counting voxel centres.
    bool subVoxelDensity = false;
    /// Measure the density on its own voxel lattice over densityBox (a spacing incommensurate
    /// with a lattice's cells, so periodic features do not alias with the voxels).
    std::optional<double> densityVoxel{};
    /// Measure the density over densityBox on the job's own voxels instead (the box a mask of the
    /// job's domain, when it lies within it): the solve's leaves are then the grid's, and a
    /// GridValueMemo under the solid hands the grid their values (each band leaf evaluated once).
    /// Set where the job's voxel resolves the field well enough (a Gaussian lattice's sigma).
    bool densityOnJobVoxels = false;
    /// Leaves per stack along z in which the job evaluates its grids of the domain and solves this
    /// level on the recipe's lattice (SparseOptions::stackLeaves): set by a Gaussian strut lattice
    /// evaluated strut by strut (nothing tiled), whether its level is solved or given, so that a
    /// solved job and one given the solved level evaluate the same batches.
    int stackLeaves = 1;
    /// The bound CoarseNodes has on the job's lattice of a voxel (StrutConvolution::coarseBound),
    /// where a strut lattice's grids take their values from nodes every second voxel at that voxel,
    /// else 0: the report states it.
    std::function<double(double voxel)> gridNodesBound{};
    /// The solid repeats with this period deeper than densityReach inside densityBox (a box frame
    /// of identical cells): the density is measured on one period of the interior, weighted
    /// (periodicPieces()), instead of the whole box.
    std::optional<Vec3d> densityPeriod{};
    double densityReach = 0.0;
    /// Along these axes the solid is its own mirror image about the middle of densityBox, so
    /// periodicPieces() measures one face zone for both.
    std::array<bool, 3> densityMirror{};
    /// The solid is its own image when x and y are swapped about densityBox's corner, so
    /// periodicPieces() measures one of each piece and its transpose.
    bool densitySwapXY = false;
    /// The field the density solve measures when it is not the solid's indicator (the same
    /// values; e.g. without a tiling whose tables would not pay off on the measuring pieces).
    FieldPtr densityIndicator{};
    /// How the printed mesh holds this lattice, so the job can measure the lattice's share of its
    /// region from the mesh (the volume a user gets) and compare it with the solve's.
    struct MeshShare {
        std::string meshOf;  ///< the node whose mesh holds the lattice (an infill, or the lattice)
        /// mm³ of the part the region lies in (its mesh, read after the parts are built); 0 when
        /// the part is not a mesh
        std::function<double()> partVolume{};
        bool skinned = false;  ///< the mesh also holds a skin: the part outside the region
    };
    /// Set by placements that mask the density (infill, `within:`); a lattice meshed alone over
    /// its density box needs none.
    std::optional<MeshShare> meshShare{};
    /// A sheet of a constant `thickness:` in mm around @a mid's zero set: the job measures the
    /// walls it really has over one @a cell (measureSheetWalls()) and warns when they miss.
    struct WallCheck {
        FieldPtr mid;
        FieldPtr sheet;  ///< solid where <= 0
        Box3 cell;
        double thickness = 0.0;
    };
    std::optional<WallCheck> wallCheck{};
    /// A sheet whose `thickness:` varies in space: what it follows (e.g. "walls 0.4 to 1 mm (ramp
    /// along x ...)"); report.html colours the part by the walls it measures.
    std::string gradedWalls{};
    /// The solid's level as the recipe's `level:` key means it, when the two differ (a Gaussian
    /// lattice's level is the iso-value t, its solid's the isolated strut's radius in mm).
    std::function<double(double level)> recipeLevel{};
};

/// A lattice whose level follows a target-density field (GradedLevel); the job reports its
/// achieved density slab by slab along `axis`.
struct GradedNode {
    std::string name;
    std::string description;  ///< e.g. "gyroid network"
    std::string density;      ///< e.g. "ramp along z from 0.1 to 0.4"
    FieldPtr node;            ///< the GradedLevel
    FieldPtr densityField;    ///< the target density
    int axis = 2;             ///< slabs are taken along this axis
    double slab = 0.0;        ///< slab thickness (mm): one cell along the axis
};

/// A strut lattice's frame, for `outputs: {frame: F}`: nodes, struts and the radius at each
/// strut end at the solved level (radii() is called after the levels are solved).
struct StrutFrameRecord {
    std::string name;
    std::vector<Vec3d> nodes;
    std::vector<std::array<int, 2>> struts;
    std::function<std::vector<std::array<double, 2>>()> radii;
};

/// A solid whose resin traps get drain channels once its levels are solved (`drain:` on an
/// infill or a shell): the Job finds the traps and gives the node its channels.
struct DrainRequest {
    std::string name;   ///< the field
    std::string where;  ///< file:line:col of `drain:`
    std::shared_ptr<DrainedSolid> node;
    FieldPtr part;            ///< the part: a channel ends outside it (null: outside the solid and its cavities)
    double diameter = 0.0;    ///< mm
    double wall = 0.0;        ///< the skin's or shell's thickness (mm): the traps are searched finer than it
    Vec3d up{0.0, 0.0, 1.0};  ///< the build direction (unit): channels leave each cavity's lowest point along it
};

class FieldBuilder;
class ParametricSurface;

/// An equation used IntraLattice's unit-box coordinates u, v, w where no frame gives the box (a
/// field built for itself, not as a strut `radius:`). FieldBuilder::buildAll() lets a field with
/// it wait for a strut frame to build it with that frame's box.
class UnitBoxNeeded : public InputError {
public:
    using InputError::InputError;
};

/// One node type of the recipe language: the key that names it, its valid keys (with their value
/// schemas, defaults and meanings: the one table schema, key checks and docs come from), its builder.
struct NodeType {
    std::string key;
    std::vector<KeySpec> keys;
    std::function<FieldPtr(FieldBuilder&, const RecipeNode& spec, const std::string& name)> build;
};

/// Builds fields by name on demand, once each, rejecting cycles and unknown names.
class FieldBuilder {
public:
    /// Warnings of the nodes go to @a context (it must outlive the builder).
    FieldBuilder(const Recipe& recipe, JobContext& context);

    /// The field called @a name in the recipe. A `surface` node is refused here (it is not a
    /// field); surface() takes one.
    FieldPtr field(const std::string& name);
    /// Builds every field of `fields:` (so a mistake anywhere is reported before any work) and
    /// returns the result. A field whose equations use u, v, w is left to the strut frame that
    /// takes it as its `radius:`; one that no frame took is an error.
    FieldPtr buildAll();
    /// A parametric surface: the name of a `surface` node or an inline `{surface: ...}`.
    std::shared_ptr<const ParametricSurface> surface(const RecipeNode& spec, const std::string& name);
    /// A field given either by name (a string) or inline (a map); @a name labels inline ones.
    FieldPtr operand(const RecipeNode& spec, const std::string& name);

    /// Level nodes in dependency order (a node's inputs come before it).
    const std::vector<LevelNode>& levelNodes() const { return mLevelNodes; }
    void addLevelNode(LevelNode node) { mLevelNodes.push_back(std::move(node)); }
    /// The level node called @a name, or null (nodes such as `infill` set its density).
    LevelNode* findLevelNode(const std::string& name)
    {
        for (LevelNode& n : mLevelNodes)
            if (n.name == name) return &n;
        return nullptr;
    }

    /// Work a node defers until every field is built (a mesh is converted once all its users
    /// have said how deep a band they need). The Job runs these in order, timed, before solving.
    struct Preparation {
        std::string stage;
        std::function<void()> run;
    };
    void addPreparation(Preparation p) { mPreparations.push_back(std::move(p)); }
    const std::vector<Preparation>& preparations() const { return mPreparations; }
    /// Entries a node adds to report.json; called on the report as it stands (levels, result
    /// and mesh filled in as far as the job got).
    void addReporter(std::function<void(nlohmann::json&)> r) { mReporters.push_back(std::move(r)); }
    const std::vector<std::function<void(nlohmann::json&)>>& reporters() const { return mReporters; }
    /// Graded-density lattices, in build order.
    const std::vector<GradedNode>& gradedNodes() const { return mGradedNodes; }
    void addGradedNode(GradedNode node) { mGradedNodes.push_back(std::move(node)); }
    /// Drain channels to plan once the levels are solved, in build order.
    const std::vector<DrainRequest>& drains() const { return mDrains; }
    void addDrain(DrainRequest d) { mDrains.push_back(std::move(d)); }
    /// Strut frames, in build order (the fields the result uses).
    const std::vector<StrutFrameRecord>& strutFrames() const { return mStrutFrames; }
    void addStrutFrame(StrutFrameRecord frame) { mStrutFrames.push_back(std::move(frame)); }
    /// Passes a warning to the job's context (it lands in report.json too).
    void warn(const std::string& code, const std::string& message, nlohmann::json details = nlohmann::json::object())
    {
        mContext.warn(code, message, std::move(details));
    }
    JobContext& context() const { return mContext; }
    const Recipe& recipe() const { return mRecipe; }

    /// While alive, equations may use IntraLattice's unit-box coordinates u, v, w: x, y, z scaled
    /// to [0, 1] over @a box (a strut frame's bounding box, for its `radius:`). Named fields that
    /// use them are built once per box.
    class UnitBoxScope {
    public:
        UnitBoxScope(FieldBuilder& builder, const Box3& box);
        ~UnitBoxScope();
        UnitBoxScope(const UnitBoxScope&) = delete;
        UnitBoxScope& operator=(const UnitBoxScope&) = delete;

    private:
        FieldBuilder& mBuilder;
        std::optional<Box3> mPrevious;
    };
    /// The box u, v, w refer to, if a UnitBoxScope is open.
    const std::optional<Box3>& unitBox() const { return mUnitBox; }
    /// Called by equations that read u, v or w (so the field being built is marked as depending
    /// on the box).
    void noteUnitBoxUse() { ++mUnitBoxUses; }
    /// Every node type the recipe language knows.
    static const std::vector<NodeType>& nodeTypes();

private:
    FieldPtr buildSpec(const RecipeNode& spec, const std::string& name);
    /// field() without the check that refuses surfaces.
    FieldPtr anyField(const std::string& name);

    const Recipe& mRecipe;
    JobContext& mContext;
    std::map<std::string, FieldPtr> mBuilt;
    std::vector<std::string> mInProgress;
    std::vector<LevelNode> mLevelNodes;
    std::vector<Preparation> mPreparations;
    std::vector<std::function<void(nlohmann::json&)>> mReporters;
    std::vector<GradedNode> mGradedNodes;
    std::vector<StrutFrameRecord> mStrutFrames;
    std::vector<DrainRequest> mDrains;
    std::optional<Box3> mUnitBox;
    std::size_t mUnitBoxUses = 0;
    /// Named fields whose equations use u, v, w, with the box they were built for.
    std::map<std::string, Box3> mUnitBoxOf;
};

/// Reads `solid:` of a lattice node: `network` (f <= level, the default) or `sheet` (|f| <= level).
SolidSide readSolidSide(const RecipeNode& spec);
/// Keys several node types share, each written once.
KeySpec solidKey();    ///< `solid:` network or sheet
KeySpec levelKey();    ///< `level:` c or t
KeySpec densityKey();  ///< `density:` a number in (0, 1)
/// A density that may also be a map grading it point by point.
nlohmann::json gradedDensitySchema();
/// `{along, x, origin}`: a frame field (orient nodes and `axes:`).
nlohmann::json orientationSchema();

/// Whether a lattice node must state its level.
enum class LevelRule {
    Optional,         ///< `level:` or `density:` or else the default level
    Required,         ///< `level:` or `density:` (a sheet has no natural level)
    SolvedElsewhere,  ///< another node's density solves it (an infill's lattice)
};
/// Reads `level:` / `density:` of a lattice node and makes its solid from @a raw: at the stated
/// level, unsolved for a density (node.density is set; the Job solves it), or at @a defaultLevel.
/// A sheet's level must be > 0. Sets node.solid and returns it.
std::shared_ptr<LevelSolid> readLevelKeys(const RecipeNode& spec, LevelNode& node, FieldPtr raw, SolidSide side,
                                          double defaultLevel, LevelRule rule);

/// Fails at a `stiffness:` or `optimize:` key that reached a node builder: the job resolves them
/// (engine/jobs/PropertyDesign) into `density:` and `sigma:` before it builds fields.
[[noreturn]] void refuseUnresolvedDesign(const RecipeNode& key);

/// LatticeNodes.cpp: `offset: m` of a network (@a side must be Below): @a raw moved m mm along its
/// unit gradient (a one-sided GradientShift); @a cell (0: none) for the large-offset warning.
/// @a description receives ", offset m mm (gradient shift)".
FieldPtr networkOffset(FieldBuilder& builder, const RecipeNode& spec, FieldPtr raw, SolidSide side,
                       const std::string& name, double cell, std::string& description);

/// Node types by family; each family lives in its own file.
void addShapeNodeTypes(std::vector<NodeType>& types);    // ShapeNodes.cpp: primitives, booleans, transforms
void addLatticeNodeTypes(std::vector<NodeType>& types);  // LatticeNodes.cpp: tpms
void addStrutNodeTypes(std::vector<NodeType>& types);    // StrutNodes.cpp: strut lattices
void addDesignNodeTypes(std::vector<NodeType>& types);   // DesignNodes.cpp: meshes, shells, infill
void addExprNodeTypes(std::vector<NodeType>& types);     // ExprNodes.cpp: user equations
void addFalloffNodeTypes(std::vector<NodeType>& types);  // FalloffNodes.cpp: point and curve fields

/// DesignNodes.cpp: true when an `infill` node solves the level of the lattice field @a name (its
/// `density:` counts for that lattice, which then needs no level of its own).
bool levelSolvedByInfill(const Recipe& recipe, const std::string& name);
/// DesignNodes.cpp: the enclosed volume (mm³) of the mesh behind the part field @a part, read when
/// called (after the parts are built); 0 when @a part is not a mesh part.
std::function<double()> partMeshVolume(const FieldPtr& part);
/// The bounding box of the part an `infill` fills with the lattice @a name (the part named, not
/// inline), if any: a box frame without a `domain:` fills it.
std::optional<Box3> infillPartBox(FieldBuilder& builder, const std::string& name);
/// DesignNodes.cpp: wraps a lattice's raw field in the conformal frame given by @a frame
/// (`{cylinder: ...}` or `{sphere: ...}`); @a cell is the lattice's cell size per axis.
FieldPtr applyFrame(const RecipeNode& frame, FieldPtr raw, const Vec3d& cell);

}  // namespace voxlat
