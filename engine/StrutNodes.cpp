// Recipe node types for strut lattices (issue 3).
#include "engine/FieldBuilder.h"

namespace voxlat {

void addStrutNodeTypes(std::vector<NodeType>& /*types*/) {}

}  // namespace voxlat
