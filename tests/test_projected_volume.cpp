// projectedVolumeInBox() and crossSectionArea(): the volume a projected, box-cut mesh will hold,
// against closed forms (a ball cut by the faces of a box) and brute force (a gyroid's section).
#include "engine/core/SparseEvaluator.h"
#include "fields/levels/LevelSolid.h"
#include "fields/shapes/Cylinder.h"
#include "fields/shapes/Sphere.h"
#include "fields/tpms/TpmsField.h"
#include "mesher/clip/BoxClip.h"
#include "mesher/tolerance/ProjectedVolume.h"

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <cmath>
#include <numbers>

using namespace voxlat;

namespace {

/// The volume of a ball of radius @a r whose centre lies @a d from a plane, on the centre's side
/// (the ball less its cap beyond the plane, for d < r).
double ballOnOneSide(double r, double d)
{
    const double h = r - d;  // the cap's height
    return 4.0 / 3.0 * std::numbers::pi * r * r * r - std::numbers::pi * h * h * (3.0 * r - h) / 3.0;
}

/// The field sampled on a grid of @a voxel from @a box's corner, running two voxels past it.
openvdb::FloatGrid::Ptr pastTheBox(const FieldNode& field, const Box3& box, double voxel)
{
    SparseOptions options;
    options.margin = 2;
    return evaluateSparse(field, Domain::fromBox(box, voxel), options);
}

/// The finished mesh's way, in full: marching cubes of @a grid, every vertex projected onto
/// @a field, the mesh cut by @a box and capped (clipToBox(), CGAL's caps); its volume.
double projectedAndCut(const openvdb::FloatGrid& grid, const FieldNode& field, const Box3& box, double voxel)
{
    TriangleMesh mesh = marchingCubes(grid, 0.0f);
    const ProjectionOptions po{0.0, 0.5 * voxel, 1e-6, 12};
    projectToSurface(mesh, field, po);
    BoxClipOptions co{po};
    const BoxClipStats cut = clipToBox(mesh, field, box, co);
    EXPECT_TRUE(cut.ok) << cut.failure;
    return mesh.volume();
}

}  // namespace

TEST(ProjectedVolume, ABallCutByOneFaceHoldsItsVolumeWithTheExactCap)
{
    // Centre 1.6 mm inside the face x = 10, radius 3.7: the cap beyond the face is cut off, and
    // the cross-section there is a disc of radius sqrt(r^2 - d^2).
    const double r = 3.7, d = 1.6, voxel = 0.25;
    const Box3 box{Vec3d(0.0), Vec3d(10.0)};
    const Sphere ball(Vec3d(10.0 - d, 5.02, 4.97), r);
    const openvdb::FloatGrid::Ptr grid = pastTheBox(ball, box, voxel);
    ProjectionOptions po{0.0, 0.5 * voxel, 1e-6, 12};
    const ProjectedVolume all = projectedVolumeInBox(*grid, ball, box, po, 1);
    const double exact = ballOnOneSide(r, d);
    const double disc = std::numbers::pi * (r * r - d * d);
    EXPECT_NEAR(all.capArea, disc, 5e-3 * disc);  // the mesh's section: chords of the circle
    // Projected, the chords alone are left: a little inside the ball, well within 0.3 %.
    EXPECT_NEAR(all.volume, exact, 3e-3 * exact) << "unprojected " << all.unprojected;
    EXPECT_LT(std::abs(all.volume - exact), std::abs(all.unprojected - exact));
    EXPECT_EQ(all.sampled + all.cut, all.triangles);
    // One triangle in seven stands for the rest.
    const ProjectedVolume sampled = projectedVolumeInBox(*grid, ball, box, po, 7);
    EXPECT_LT(sampled.sampled, all.sampled / 6 + 1);
    EXPECT_NEAR(sampled.volume, exact, 4e-3 * exact);
}

TEST(ProjectedVolume, ABallCutByEveryFaceAndCornerHoldsItsVolume)
{
    // A ball about the box's corner (10, 10, 10) with radius 4: an eighth of it is inside. Every
    // face it meets but x = max has n_x = 0 there; the section on x = 10 is a quarter disc.
    const double r = 4.0, voxel = 0.2;
    const Box3 box{Vec3d(0.0), Vec3d(10.0)};
    const Sphere ball(Vec3d(10.0), r);
    const openvdb::FloatGrid::Ptr grid = pastTheBox(ball, box, voxel);
    const ProjectedVolume v = projectedVolumeInBox(*grid, ball, box, {0.0, 0.5 * voxel, 1e-6, 12}, 1);
    const double eighth = std::numbers::pi * r * r * r / 6.0;
    EXPECT_NEAR(v.capArea, std::numbers::pi * r * r / 4.0, 2e-3 * std::numbers::pi * r * r / 4.0);
    EXPECT_NEAR(v.volume, eighth, 3e-3 * eighth) << "unprojected " << v.unprojected;
}

TEST(ProjectedVolume, BallsAboutABoxEdgeHoldAQuarterOfTheirVolume)
{
    // Balls centred on the box's edge x = 10, y = 10 at several heights and offsets: a quarter of
    // each is inside, and many triangles are cut by both faces (a corner clipped off by the first
    // must still be clipped by the second).
    const Box3 box{Vec3d(0.0), Vec3d(10.0)};
    const double voxel = 0.2;
    for (const double shift : {0.0, 0.037, 0.071, 0.113}) {
        const double r = 3.1 + shift;
        const Sphere ball(Vec3d(10.0, 10.0, 4.0 + 3.0 * shift), r);
        const openvdb::FloatGrid::Ptr grid = pastTheBox(ball, box, voxel + 0.1 * shift);
        const ProjectedVolume v =
            projectedVolumeInBox(*grid, ball, box, {0.0, 0.5 * (voxel + 0.1 * shift), 1e-6, 12}, 1);
        const double quarter = std::numbers::pi * r * r * r / 3.0;
        EXPECT_NEAR(v.volume, quarter, 3e-3 * quarter) << shift;
    }
}

TEST(ProjectedVolume, AWideSlabWhoseFacesMissTheSamplesHoldsItsVolume)
{
    // W9's gyroid (10 mm cells, level -0.618) at 0.3 mm in a slab 50.1 mm wide: the faces lie
    // between the samples, and the section's edge term weighs each crossing of the edge
    // x = y = 50.1 by 50.1 x 50.1 mm. A triangle cut by both faces once kept a corner past the
    // second and lost a crossing: 20 % light.
    const LevelSolid gyroid(std::make_shared<TpmsField>(TpmsType::Gyroid, Vec3d(10.0)), SolidSide::Below, -0.618);
    const double voxel = 0.3;
    const Box3 box{Vec3d(0.0, 0.0, 24.0), Vec3d(50.1, 50.1, 30.0)};
    const openvdb::FloatGrid::Ptr grid = pastTheBox(gyroid, box, voxel);
    const double finished = projectedAndCut(*grid, gyroid, box, voxel);
    const ProjectedVolume v = projectedVolumeInBox(*grid, gyroid, box, {0.0, 0.5 * voxel, 1e-6, 12}, 1);
    EXPECT_NEAR(v.volume, finished, 1e-3 * finished) << "unprojected " << v.unprojected;
}

TEST(ProjectedVolume, SameBitsForAnyThreadCount)
{
    TpmsField gyroid(TpmsType::Gyroid, Vec3d(5.0));
    const Box3 box{Vec3d(0.0), Vec3d(12.0)};
    const openvdb::FloatGrid::Ptr grid = pastTheBox(gyroid, box, 0.3);
    auto run = [&](int threads) {
        tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
        return projectedVolumeInBox(*grid, gyroid, box, {0.0, 0.15, 1e-6, 12}, 3);
    };
    const ProjectedVolume one = run(1), two = run(2);
    EXPECT_EQ(one.volume, two.volume);
    EXPECT_EQ(one.capArea, two.capArea);
}

TEST(ProjectedVolume, ThinCylindersAsTheFinishedMeshHoldsThemAndAsTheSurfaceDoes)
{
    // Cylinders of radius 0.6 at 0.3 mm (a strut two voxels thick) through the face x = 10: along
    // x and along z on the face (half inside). The estimate is the projected mesh cut by
    // the box (made in full here and capped by CGAL), whose chords leave it 4 % light; `surface`
    // is the cylinders' own volume within the box (analytic).
    const Box3 box{Vec3d(0.0), Vec3d(10.0)};
    const double voxel = 0.3, r = 0.6, area = std::numbers::pi * r * r;
    struct Case {
        Vec3d axis;
        double inside;  // the exact volume within the box
    };
    for (const Case& c : {Case{Vec3d(1, 0, 0), area * 10.0}, Case{Vec3d(0, 0, 1), area * 10.0 / 2.0}}) {
        const Cylinder cylinder(Vec3d(10.0, 5.03, 4.98), c.axis, r, 40.0);
        const openvdb::FloatGrid::Ptr grid = pastTheBox(cylinder, box, voxel);
        const ProjectedVolume v = projectedVolumeInBox(*grid, cylinder, box, {0.0, 0.5 * voxel, 1e-6, 12}, 1);
        const double finished = projectedAndCut(*grid, cylinder, box, voxel);
        // The finished mesh puts its crease points on the surface where the estimate's chords
        // cross the face: along a cut through the axis (the worst case) 0.55 % apart.
        EXPECT_NEAR(v.volume, finished, 6e-3 * finished) << c.axis;
        EXPECT_LT(v.volume, 0.98 * c.inside) << c.axis;
        EXPECT_NEAR(v.surface, c.inside, 5e-3 * c.inside) << c.axis;
    }
}

TEST(ProjectedVolume, AGyroidCutByItsBoxAsTheFinishedMeshHoldsIt)
{
    // A gyroid network meets every face and edge of the box: the estimate against the same mesh
    // made in full and cut by CGAL, with every triangle projected and with one in five.
    const LevelSolid gyroid(std::make_shared<TpmsField>(TpmsType::Gyroid, Vec3d(6.0)), SolidSide::Below, -0.6);
    const double voxel = 0.3;
    // 30 mm: the section's edge term weighs a crossing at height z by 30 x 30 x z mm (a
    // triangle clipped by two faces once kept a corner past the second: 20 % off on W9's cube).
    const Box3 box{Vec3d(0.11, -0.07, 0.05), Vec3d(30.2, 29.9, 30.04)};
    const openvdb::FloatGrid::Ptr grid = pastTheBox(gyroid, box, voxel);
    const ProjectionOptions po{0.0, 0.5 * voxel, 1e-6, 12};
    const double finished = projectedAndCut(*grid, gyroid, box, voxel);
    const ProjectedVolume all = projectedVolumeInBox(*grid, gyroid, box, po, 1);
    EXPECT_NEAR(all.volume, finished, 1e-3 * finished) << "unprojected " << all.unprojected;
    const ProjectedVolume fifth = projectedVolumeInBox(*grid, gyroid, box, po, 5);
    EXPECT_LT(fifth.sampled, all.sampled / 4);
    EXPECT_NEAR(fifth.volume, finished, 2e-3 * finished);
}
