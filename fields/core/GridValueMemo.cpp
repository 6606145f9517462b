#include "fields/core/GridValueMemo.h"

#include <algorithm>
#include <bit>

namespace voxlat {

std::size_t GridValueMemo::KeyHash::operator()(const Key& k) const
{
    std::uint64_t h = 0x9E3779B97F4A7C15ull;
    auto mix = [&h](std::uint64_t v) { h ^= v + 0x9E3779B97F4A7C15ull + (h << 6) + (h >> 2); };
    for (const double v : {k.ox, k.oy, k.oz, k.sx, k.sy, k.sz}) mix(std::bit_cast<std::uint64_t>(v));
    mix(std::uint64_t(k.nx) << 40 | std::uint64_t(k.ny) << 20 | std::uint64_t(k.nz));
    return std::size_t(h);
}

void GridValueMemo::keep(bool on, std::size_t maxBytes) const
{
    mShards.reset();
    mBytes = 0;
    mMaxBytes = maxBytes;
    if (on) mShards = std::make_unique<std::array<Shard, kShards>>();
}

std::size_t GridValueMemo::keptBytes() const
{
    return mBytes.load();
}

void GridValueMemo::gridValues(const GridBatch& batch, std::span<double> out) const
{
    if (!mShards) {
        mOperand->gridValues(batch, out);
        return;
    }
    const Key key{batch.origin.x(),  batch.origin.y(), batch.origin.z(), batch.spacing.x(), batch.spacing.y(),
                  batch.spacing.z(), batch.nx,         batch.ny,         batch.nz};
    const std::size_t hash = KeyHash{}(key);
    Shard& shard = (*mShards)[(hash >> 7) % kShards];
    const std::size_t n = batch.size();
    {
        std::lock_guard<std::mutex> lock(shard.mutex);
        const auto found = shard.values.find(key);
        if (found != shard.values.end()) {
            std::copy(found->second.begin(), found->second.end(), out.begin());
            return;
        }
    }
    mOperand->gridValues(batch, out);
    const std::size_t bytes = n * sizeof(double);
    if (mBytes.fetch_add(bytes) + bytes > mMaxBytes) {
        mBytes.fetch_sub(bytes);
        return;
    }
    std::lock_guard<std::mutex> lock(shard.mutex);
    shard.values.try_emplace(key, out.begin(), out.begin() + std::ptrdiff_t(n));
}

}  // namespace voxlat
