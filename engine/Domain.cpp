#include "engine/Domain.h"

#include <algorithm>
#include <cmath>

namespace voxlat {

Domain Domain::fromBox(const Box3& box, double voxel)
{
    Domain d;
    d.voxel = voxel;
    d.box.min = box.min;
    int n[3];
    for (int a = 0; a < 3; ++a) {
        n[a] = std::max(1, int(std::llround((box.max[a] - box.min[a]) / voxel)));
        d.box.max[a] = box.min[a] + n[a] * voxel;
    }
    d.dims = openvdb::Coord(n[0], n[1], n[2]);
    return d;
}

openvdb::math::Transform::Ptr Domain::transform() const
{
    auto xform = openvdb::math::Transform::createLinearTransform(voxel);
    xform->postTranslate(box.min + Vec3d(0.5 * voxel));
    return xform;
}

}  // namespace voxlat
