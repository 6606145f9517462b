// Recipe node types for user equations (issue 7).
#include "engine/FieldBuilder.h"

namespace voxlat {

void addExprNodeTypes(std::vector<NodeType>& /*types*/) {}

}  // namespace voxlat
