/// @file FieldBuilder.h
/// @brief Turns a recipe's `fields:` map into a graph of field nodes.
#pragma once

#include "engine/Recipe.h"
#include "fields/LevelSolid.h"

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
    std::optional<double> density;  ///< target relative density
    /// Where the density is measured: the domain unless a node narrows it (a strut lattice
    /// measures over its frame's bounding box).
    std::optional<Box3> densityBox;
    /// Called with the solved level after a density solve (checks and notes that need it).
    std::function<void(double level)> onSolved;
    /// Measure the density with sub-voxel coverage rather than by counting voxel centres.
    bool subVoxelDensity = false;
    /// Measure the density on its own voxel lattice over densityBox (a spacing incommensurate
    /// with a lattice's cells, so periodic features do not alias with the voxels).
    std::optional<double> densityVoxel;
};

class FieldBuilder;

/// One node type of the recipe language: the key that names it, its valid keys, its builder.
struct NodeType {
    std::string key;
    std::vector<std::string> keys;
    std::function<FieldPtr(FieldBuilder&, const RecipeNode& spec, const std::string& name)> build;
};

/// Builds fields by name on demand, once each, rejecting cycles and unknown names.
class FieldBuilder {
public:
    explicit FieldBuilder(const Recipe& recipe);

    /// The field called @a name in the recipe.
    FieldPtr field(const std::string& name);
    /// A field given either by name (a string) or inline (a map); @a name labels inline ones.
    FieldPtr operand(const RecipeNode& spec, const std::string& name);

    /// Level nodes in dependency order (a node's inputs come before it).
    const std::vector<LevelNode>& levelNodes() const { return mLevelNodes; }
    void addLevelNode(LevelNode node) { mLevelNodes.push_back(std::move(node)); }
    const Recipe& recipe() const { return mRecipe; }

    /// Every node type the recipe language knows.
    static const std::vector<NodeType>& nodeTypes();

private:
    FieldPtr buildSpec(const RecipeNode& spec, const std::string& name);

    const Recipe& mRecipe;
    std::map<std::string, FieldPtr> mBuilt;
    std::vector<std::string> mInProgress;
    std::vector<LevelNode> mLevelNodes;
};

/// Node types by family; each family lives in its own file.
void addShapeNodeTypes(std::vector<NodeType>& types);    // ShapeNodes.cpp: primitives, booleans, transforms
void addLatticeNodeTypes(std::vector<NodeType>& types);  // LatticeNodes.cpp: tpms
void addStrutNodeTypes(std::vector<NodeType>& types);    // StrutNodes.cpp: strut lattices
void addDesignNodeTypes(std::vector<NodeType>& types);   // DesignNodes.cpp: meshes, shells, infill
void addExprNodeTypes(std::vector<NodeType>& types);     // ExprNodes.cpp: user equations

}  // namespace voxlat
