/// @file NodeStencilsAvx512.cpp
/// nodePassesLoop built for AVX-512F without contraction: the baseline build's doubles.
#include "fields/struts/NodeStencils.h"

namespace voxlat::node_stencils {

void nodePassesAvx512(const NodePasses& p)
{
    nodePassesLoop(p);
}

}  // namespace voxlat::node_stencils
