/// @file NodeStencilsAvx2.cpp
/// nodePassesLoop built for AVX2 without FMA or contraction: the baseline build's doubles.
#include "fields/struts/NodeStencils.h"

namespace voxlat::node_stencils {

void nodePassesAvx2(const NodePasses& p)
{
    nodePassesLoop(p);
}

}  // namespace voxlat::node_stencils
