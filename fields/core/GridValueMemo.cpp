#include "fields/core/GridValueMemo.h"

#include <tbb/parallel_for.h>

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
            std::copy(found->second, found->second + n, out.begin());
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
    if (shard.values.contains(key)) {  // kept by another thread meanwhile: the same values
        mBytes.fetch_sub(bytes);
        return;
    }
    double* kept = place(shard, n);
    std::copy(out.begin(), out.begin() + std::ptrdiff_t(n), kept);
    shard.values.emplace(key, kept);
}

void GridValueMemo::dropOutside(Interval levels) const
{
    if (!mShards) return;
    // Shard by shard (each decided alone: the same batches kept for any thread count), the kept
    // values copied into fresh blocks and the old blocks freed: one shard's values held twice.
    tbb::parallel_for(0, kShards, [&](int s) {
        Shard& shard = (*mShards)[std::size_t(s)];
        std::lock_guard<std::mutex> lock(shard.mutex);
        std::vector<std::unique_ptr<double[]>> old;
        old.swap(shard.blocks);
        shard.next = nullptr;
        shard.left = 0;
        std::size_t dropped = 0;
        for (auto it = shard.values.begin(); it != shard.values.end();) {
            const Key& k = it->first;
            const std::size_t n = std::size_t(k.nx) * std::size_t(k.ny) * std::size_t(k.nz);
            if (!readAt(k, it->second, levels)) {
                dropped += n * sizeof(double);
                it = shard.values.erase(it);
                continue;
            }
            it->second = std::copy(it->second, it->second + n, place(shard, n)) - n;
            ++it;
        }
        mBytes.fetch_sub(dropped);
    });
}

bool GridValueMemo::readAt(const Key& k, const double* values, Interval levels) const
{
    // A value in the band: the bound, which holds it, meets the band too. Decided without the
    // bound, which costs a twentieth of the batch's evaluation on a wireframe.
    const auto [lo, hi] = std::minmax_element(values, values + std::size_t(k.nx) * k.ny * k.nz);
    if (!(*hi < levels.lo || *lo > levels.hi)) return true;
    // The batch's points grown by one spacing, and by a millionth of one more: the evaluator's
    // box (from index coordinates) may differ from this one in the last bits.
    const Vec3d origin(k.ox, k.oy, k.oz), spacing(k.sx, k.sy, k.sz), grow = 1.000001 * spacing;
    const Vec3d last((k.nx - 1) * spacing.x(), (k.ny - 1) * spacing.y(), (k.nz - 1) * spacing.z());
    const Interval b = mOperand->bound(Box3{origin - grow, origin + last + grow});
    return !(b.hi < levels.lo || b.lo > levels.hi);
}

double* GridValueMemo::place(Shard& shard, std::size_t n)
{
    if (shard.left < n) {
        const std::size_t size = std::max(kBlockDoubles, n);
        shard.blocks.push_back(std::make_unique_for_overwrite<double[]>(size));
        shard.next = shard.blocks.back().get();
        shard.left = size;
    }
    double* at = shard.next;
    shard.next += n;
    shard.left -= n;
    return at;
}

}  // namespace voxlat
