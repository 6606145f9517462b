/// @file MeshDesignSpace.h
/// @brief A part given as a triangle mesh: checks, repair, orientation, and its narrow-band
/// signed distance grid (the design space a lattice fills).
#pragma once

#include "engine/parts/MeshReader.h"
#include "fields/shapes/MeshDistance.h"

#include <nlohmann/json.hpp>

#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

namespace voxlat {

struct MeshSpaceOptions {
    double voxel = 0.1;
    /// World position of one grid sample: the domain's first voxel centre, so that a job's voxel
    /// centres are the grid's own samples (looked up, not interpolated).
    Vec3d sampleOrigin{0.0};
    bool repair = false;           ///< fill small holes instead of refusing an open mesh
    std::optional<double> unitMm;  ///< millimetres per file unit, when the recipe says
    std::optional<Box3> domain;    ///< the recipe's domain, to catch a mesh far larger
};

/// Checks a part mesh on construction (closed, manifold, orientable; repairs small holes when
/// asked; suspicious sizes warned about) and converts it to a signed distance grid on build().
/// Every refusal is an InputError whose message starts with the file name as the user wrote it.
class MeshDesignSpace {
public:
    MeshDesignSpace(PartMesh part, std::string shown, const MeshSpaceOptions& options);

    /// Grows the band of exact distances inside the surface to at least @a mm (a shell or a skin
    /// reads distances that deep). Call before build().
    void requireInteriorBand(double mm) { mInteriorMm = std::max(mInteriorMm, mm); }

    /// Converts the mesh (once; later calls return at once; safe from many threads), then checks
    /// each shell's orientation against the grid and flips shells that are inside out.
    void build();
    /// The distance field (builds first if needed).
    std::shared_ptr<const MeshDistance> distance();

    const std::string& shown() const { return mShown; }
    double voxel() const { return mVoxel; }
    const TriangleMesh& mesh() const { return mMesh; }
    /// The mesh's bounding box (millimetres, after units).
    Box3 bounds() const { return mBounds; }
    /// The mesh's enclosed volume by the divergence theorem (after orientation fixes).
    double meshVolume() const { return mMesh.volume(); }
    /// The part's volume measured on the grid: sub-voxel coverage of each sample's cell (after
    /// build()).
    double gridVolume() const { return mGridVolume; }
    const std::vector<std::string>& warnings() const { return mWarnings; }
    nlohmann::json report() const;

private:
    void orientShells();
    void fillHoles(bool repair);
    void checkSize(const MeshSpaceOptions& options);
    void convert();
    /// Turns inside-out shells by @a grid's gradients, then measures the part's volume on it.
    void orientAndMeasure(const openvdb::FloatGrid::Ptr& grid);

    TriangleMesh mMesh;
    std::string mShown, mFormat;
    double mVoxel, mUnitMm = 1.0;
    bool mUnitsKnown = false;  ///< given by the recipe or the file
    Vec3d mSampleOrigin;
    Box3 mBounds;
    double mInteriorMm = 0.0;
    std::vector<std::uint32_t> mShellOf;  ///< shell (connected component) of each triangle
    std::uint32_t mShells = 0;

    std::once_flag mBuilt;
    std::shared_ptr<const MeshDistance> mDistance;
    double mGridVolume = 0.0;
    std::string mConverter = "exact distances, ray parity";  ///< which conversion made the grid

    // What the checks found and fixed, for the report.
    std::size_t mDegenerateDropped = 0, mReorientedTriangles = 0, mHolesFilled = 0, mHoleEdges = 0;
    std::size_t mFlippedShells = 0;
    std::vector<std::string> mWarnings;
};

/// The field of a part: the design space's distance, converted on first use.
class PartField final : public FieldNode, public PlaneBands {
public:
    explicit PartField(std::shared_ptr<MeshDesignSpace> space) : mSpace(std::move(space)) {}

    void values(std::span<const Vec3d> points, std::span<double> out) const override
    {
        mSpace->distance()->values(points, out);
    }
    void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const override
    {
        mSpace->distance()->gradients(points, out, grad);
    }
    void gridValues(const GridBatch& batch, std::span<double> out) const override
    {
        mSpace->distance()->gridValues(batch, out);
    }
    Interval bound(const Box3& box) const override { return mSpace->distance()->bound(box); }
    void planeValues(const GridBatch& plane, int tile, Interval band, std::span<double> out,
                     std::span<signed char> side, std::span<const TileNeed> need) const override
    {
        planeValuesOf(*mSpace->distance(), plane, tile, band, out, side, need);
    }
    bool planeCheap() const override { return true; }
    /// Known from the mesh alone: its box grown by a voxel (interpolation reaches that far).
    std::optional<Box3> support() const override;

    const std::shared_ptr<MeshDesignSpace>& space() const { return mSpace; }

private:
    std::shared_ptr<MeshDesignSpace> mSpace;
};

}  // namespace voxlat
