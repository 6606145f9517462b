#include "engine/core/Domain.h"

#include "engine/core/Errors.h"
#include "engine/core/Format.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace voxlat {

Domain Domain::fromBox(const Box3& box, double voxel)
{
    Domain d;
    d.voxel = voxel;
    d.box.min = box.min;
    int n[3];
    for (int a = 0; a < 3; ++a) {
        // In double first: a tiny voxel would overflow the integer (and OpenVDB's coordinates).
        const double count = std::round((box.max[a] - box.min[a]) / voxel);
        if (!(voxel > 0.0) || !(count <= double(kMaxVoxelsPerAxis)))
            throw InputError("a voxel of " + formatNumber(voxel) + " mm over " + formatNumber(box.max[a] - box.min[a]) +
                             " mm makes " + formatNumber(count) + " voxels along " + "xyz"[a] + ", more than the " +
                             std::to_string(kMaxVoxelsPerAxis) + " a grid can index: raise `voxel:`");
        n[a] = std::max(1, int(count));
        d.box.max[a] = box.min[a] + n[a] * voxel;
    }
    d.dims = openvdb::Coord(n[0], n[1], n[2]);
    return d;
}

Domain Domain::subDomain(const Box3& sub) const
{
    Domain d = *this;
    int first[3];
    for (int a = 0; a < 3; ++a) {
        // Voxel i is inside when min + (i + 0.5) * voxel lies in [sub.min, sub.max].
        first[a] = std::max(0, int(std::ceil((sub.min[a] - box.min[a]) / voxel - 0.5 - 1e-9)));
        const int last = std::min(dims[a] - 1, int(std::floor((sub.max[a] - box.min[a]) / voxel - 0.5 + 1e-9)));
        if (last < first[a]) throw std::invalid_argument("the box holds no voxel centre of the domain");
        d.dims[a] = last - first[a] + 1;
        d.box.min[a] = box.min[a] + first[a] * voxel;
        d.box.max[a] = d.box.min[a] + d.dims[a] * voxel;
    }
    d.latticeRoot = latticeMin();
    d.latticeOffset = latticeOffset + openvdb::Coord(first[0], first[1], first[2]);
    return d;
}

Domain Domain::grown(int voxels) const
{
    Domain d = *this;
    d.box.min -= Vec3d(voxels * voxel);
    d.box.max += Vec3d(voxels * voxel);
    d.dims += openvdb::Coord(2 * voxels);
    d.latticeRoot = latticeMin();
    d.latticeOffset = latticeOffset - openvdb::Coord(voxels);
    return d;
}

openvdb::math::Transform::Ptr Domain::transform() const
{
    auto xform = openvdb::math::Transform::createLinearTransform(voxel);
    xform->postTranslate(box.min + Vec3d(0.5 * voxel));
    return xform;
}

}  // namespace voxlat
