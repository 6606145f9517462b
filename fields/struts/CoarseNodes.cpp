/// @file CoarseNodes.cpp
/// @brief Exact nodes every second voxel, kept per lattice in blocks; eight-point midpoint
/// stencils between them.
#include "fields/struts/CoarseNodes.h"

#include "fields/struts/NodeStencils.h"
#include "fields/struts/StrutRows.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstring>
#include <mutex>
#include <unordered_map>
#include <vector>

namespace voxlat {

namespace {

constexpr int kBlockXY = 8, kBlockZ = 32;  // nodes per block along x and y, along z
constexpr std::size_t kBlockSize = std::size_t(kBlockXY) * kBlockXY * kBlockZ;
using node_stencils::floorDiv;
using node_stencils::kHalfStencil;
/// |prod_l (3.5 - l)| over l = 0..7, and 8!.
constexpr double kMidpointProduct = 43.06640625, kFactorial8 = 40320.0;
constexpr double kLebesgue = 3048.0 / 2048.0;

std::uint64_t bitsOf(double v)
{
    std::uint64_t b;
    std::memcpy(&b, &v, sizeof b);
    return b;
}

}  // namespace

namespace coarse_nodes {

struct BlockKey {
    std::array<std::uint64_t, 4> lattice;  ///< the bits of latticeMin and the voxel
    int bx, by, bz;
    bool operator==(const BlockKey&) const = default;
};

struct BlockKeyHash {
    std::size_t operator()(const BlockKey& k) const
    {
        std::uint64_t h = 1469598103934665603ull;
        auto mix = [&h](std::uint64_t v) { h ^= v + 0x9e3779b97f4a7c15ull + (h << 6) + (h >> 2); };
        for (const std::uint64_t v : k.lattice) mix(v);
        mix(std::uint64_t(std::uint32_t(k.bx)));
        mix(std::uint64_t(std::uint32_t(k.by)));
        mix(std::uint64_t(std::uint32_t(k.bz)));
        return std::size_t(h);
    }
};

struct Block {
    std::once_flag made;
    std::vector<float> values;  ///< x-major, z fastest: (x * 8 + y) * 32 + z (floats: half the memory)
};

}  // namespace coarse_nodes

using coarse_nodes::Block;
using coarse_nodes::BlockKey;
using coarse_nodes::BlockKeyHash;

double coarseNodesBound(double nodeSpacing, double sigma, const std::array<double, 3>& c8)
{
    const double k = kMidpointProduct / kFactorial8 * std::pow(nodeSpacing / sigma, 8);
    return k * (c8[2] + kLebesgue * c8[1] + kLebesgue * kLebesgue * c8[0]);
}

struct CoarseNodes::Impl {
    static constexpr int kShards = 64;
    struct Shard {
        std::mutex mutex;
        std::unordered_map<BlockKey, std::shared_ptr<Block>, BlockKeyHash> blocks;
    };
    std::array<Shard, kShards> shards;
    std::atomic<std::size_t> count{0};
    std::mutex latticeMutex;
    std::array<std::uint64_t, 4> lattice{};  ///< the lattice whose blocks are held (latticeMutex)
    bool held = false;

    /// Makes @a key the lattice held, dropping another's blocks (readers keep theirs alive).
    void hold(const std::array<std::uint64_t, 4>& key)
    {
        std::lock_guard<std::mutex> lock(latticeMutex);
        if (held && lattice == key) return;
        for (Shard& shard : shards) {
            std::lock_guard<std::mutex> shardLock(shard.mutex);
            shard.blocks.clear();
        }
        count = 0;
        lattice = key;
        held = true;
    }

    std::shared_ptr<Block> blockOf(const BlockKey& key)
    {
        Shard& shard = shards[BlockKeyHash{}(key) % kShards];
        std::lock_guard<std::mutex> lock(shard.mutex);
        std::shared_ptr<Block>& b = shard.blocks[key];
        if (!b) {
            b = std::make_shared<Block>();
            count.fetch_add(1, std::memory_order_relaxed);
        }
        return b;
    }
};

CoarseNodes::CoarseNodes() : mImpl(std::make_unique<Impl>()) {}
CoarseNodes::~CoarseNodes() = default;

std::size_t CoarseNodes::bytes() const
{
    return mImpl->count.load() * kBlockSize * sizeof(float);
}

void CoarseNodes::interpolate(const GridBatch& batch, std::span<double> out, const Exact& exact) const
{
    const int stride = batch.latticeStride;
    const double voxel = batch.voxel();
    const std::array<int, 3> n{batch.nx, batch.ny, batch.nz};
    BlockKey key{
        {bitsOf(batch.latticeMin.x()), bitsOf(batch.latticeMin.y()), bitsOf(batch.latticeMin.z()), bitsOf(voxel)},
        0,
        0,
        0};
    mImpl->hold(key.lattice);
    // Block (bx, by, bz), made by whichever thread asks first (the same doubles whichever).
    auto blockAt = [&](int bx, int by, int bz) {
        key.bx = bx;
        key.by = by;
        key.bz = bz;
        std::shared_ptr<Block> block = mImpl->blockOf(key);
        std::call_once(block->made, [&] {
            GridBatch nodesBatch;
            nodesBatch.spacing = Vec3d(2.0 * voxel);
            nodesBatch.nx = kBlockXY;
            nodesBatch.ny = kBlockXY;
            nodesBatch.nz = kBlockZ;
            const Vec3d first(2.0 * kBlockXY * bx + 0.5, 2.0 * kBlockXY * by + 0.5, 2.0 * kBlockZ * bz + 0.5);
            nodesBatch.origin = batch.latticeMin + voxel * first;
            thread_local std::vector<double> exactValues;
            exactValues.resize(kBlockSize);
            exact(nodesBatch, exactValues);
            block->values.assign(exactValues.begin(), exactValues.end());
        });
        return block;
    };
    if (stride != 1) {
        // Every point a node (an even stride from even voxels: StrutConvolution::coarseServes):
        // node (first + stride v) / 2 along each axis, copied from its block.
        const int step = stride / 2;
        const std::array<int, 3> first{batch.latticeIndex[0] / 2, batch.latticeIndex[1] / 2, batch.latticeIndex[2] / 2};
        const int bx0 = floorDiv(first[0], kBlockXY), bx1 = floorDiv(first[0] + step * (n[0] - 1), kBlockXY);
        const int by0 = floorDiv(first[1], kBlockXY), by1 = floorDiv(first[1] + step * (n[1] - 1), kBlockXY);
        const int bz0 = floorDiv(first[2], kBlockZ), bz1 = floorDiv(first[2] + step * (n[2] - 1), kBlockZ);
        const int cy = by1 - by0 + 1, cz = bz1 - bz0 + 1;
        thread_local std::vector<std::shared_ptr<Block>> blocks;
        blocks.clear();
        for (int bx = bx0; bx <= bx1; ++bx)
            for (int by = by0; by <= by1; ++by)
                for (int bz = bz0; bz <= bz1; ++bz) blocks.push_back(blockAt(bx, by, bz));
        std::size_t v = 0;
        for (int i = 0; i < n[0]; ++i) {
            const int x = first[0] + step * i, bx = floorDiv(x, kBlockXY);
            for (int j = 0; j < n[1]; ++j) {
                const int y = first[1] + step * j, by = floorDiv(y, kBlockXY);
                for (int k = 0; k < n[2]; ++k, ++v) {
                    const int z = first[2] + step * k, bz = floorDiv(z, kBlockZ);
                    const Block& block =
                        *blocks[(std::size_t(bx - bx0) * cy + std::size_t(by - by0)) * cz + std::size_t(bz - bz0)];
                    out[v] = block.values[(std::size_t(x - bx * kBlockXY) * kBlockXY + std::size_t(y - by * kBlockXY)) *
                                              kBlockZ +
                                          std::size_t(z - bz * kBlockZ)];
                }
            }
        }
        blocks.clear();
        return;
    }
    // The nodes the batch reads, per axis: node m is voxel 2m.
    std::array<int, 3> lo{}, count{};
    for (int a = 0; a < 3; ++a) {
        const int first = batch.latticeIndex[std::size_t(a)], last = first + n[std::size_t(a)] - 1;
        lo[std::size_t(a)] = floorDiv(first, 2) - (kHalfStencil - 1);
        count[std::size_t(a)] = floorDiv(last, 2) + kHalfStencil - lo[std::size_t(a)] + 1;
    }
    thread_local std::vector<double> nodes, alongX, alongXY;
    const std::size_t cx = std::size_t(count[0]), cy = std::size_t(count[1]), cz = std::size_t(count[2]);
    nodes.resize(cx * cy * cz);
    // The nodes from their blocks.
    const int bx0 = floorDiv(lo[0], kBlockXY), bx1 = floorDiv(lo[0] + count[0] - 1, kBlockXY);
    const int by0 = floorDiv(lo[1], kBlockXY), by1 = floorDiv(lo[1] + count[1] - 1, kBlockXY);
    const int bz0 = floorDiv(lo[2], kBlockZ), bz1 = floorDiv(lo[2] + count[2] - 1, kBlockZ);
    for (int bx = bx0; bx <= bx1; ++bx)
        for (int by = by0; by <= by1; ++by)
            for (int bz = bz0; bz <= bz1; ++bz) {
                const std::shared_ptr<Block> block = blockAt(bx, by, bz);
                // The part of the block within the nodes read.
                const int x0 = std::max(lo[0], bx * kBlockXY), x1 = std::min(lo[0] + count[0], (bx + 1) * kBlockXY);
                const int y0 = std::max(lo[1], by * kBlockXY), y1 = std::min(lo[1] + count[1], (by + 1) * kBlockXY);
                const int z0 = std::max(lo[2], bz * kBlockZ), z1 = std::min(lo[2] + count[2], (bz + 1) * kBlockZ);
                for (int x = x0; x < x1; ++x)
                    for (int y = y0; y < y1; ++y) {
                        const float* from =
                            block->values.data() +
                            (std::size_t(x - bx * kBlockXY) * kBlockXY + std::size_t(y - by * kBlockXY)) * kBlockZ +
                            std::size_t(z0 - bz * kBlockZ);
                        double* to = nodes.data() + (std::size_t(x - lo[0]) * cy + std::size_t(y - lo[1])) * cz +
                                     std::size_t(z0 - lo[2]);
                        std::copy(from, from + (z1 - z0), to);
                    }
            }
    const std::size_t ny = std::size_t(n[1]), nx = std::size_t(n[0]);
    alongX.resize(nx * cy * cz);
    alongXY.resize(nx * ny * cz);
    const node_stencils::NodePasses passes{nodes.data(),   lo,        count, batch.latticeIndex, n, alongX.data(),
                                           alongXY.data(), out.data()};
    if (hasAvx512Rows())
        node_stencils::nodePassesAvx512(passes);
    else if (hasAvx2Rows())
        node_stencils::nodePassesAvx2(passes);
    else
        node_stencils::nodePassesLoop(passes);
}

}  // namespace voxlat
