// Recipe node types for design spaces from meshes, shells and infill (issue 6).
#include "engine/FieldBuilder.h"

namespace voxlat {

void addDesignNodeTypes(std::vector<NodeType>& /*types*/) {}

}  // namespace voxlat
