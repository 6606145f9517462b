#include "fields/core/GridValueMemo.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <bit>
#include <cstring>
#include <iterator>
#include <stdexcept>
#include <tuple>
#include <utility>
#include <vector>

namespace voxlat {

std::size_t GridValueMemo::KeyHash::operator()(const Key& k) const
{
    std::uint64_t h = 0x9E3779B97F4A7C15ull;
    auto mix = [&h](std::uint64_t v) { h ^= v + 0x9E3779B97F4A7C15ull + (h << 6) + (h >> 2); };
    for (const double v : {k.ox, k.oy, k.oz, k.sx, k.sy, k.sz}) mix(std::bit_cast<std::uint64_t>(v));
    mix(std::uint64_t(k.nx) << 40 | std::uint64_t(k.ny) << 20 | std::uint64_t(k.nz));
    return std::size_t(h);
}

std::size_t GridValueMemo::BoxKeyHash::operator()(const BoxKey& k) const
{
    std::uint64_t h = 0x9E3779B97F4A7C15ull;
    auto mix = [&h](std::uint64_t v) { h ^= v + 0x9E3779B97F4A7C15ull + (h << 6) + (h >> 2); };
    for (const double v : {k.x0, k.y0, k.z0, k.x1, k.y1, k.z1}) mix(std::bit_cast<std::uint64_t>(v));
    return std::size_t(h);
}

Interval GridValueMemo::bound(const Box3& box) const
{
    if (!mShards) return mOperand->bound(box);
    const BoxKey key{box.min.x(), box.min.y(), box.min.z(), box.max.x(), box.max.y(), box.max.z()};
    Shard& shard = (*mShards)[(BoxKeyHash{}(key) >> 7) % kShards];
    {
        std::lock_guard<std::mutex> lock(shard.mutex);
        const auto found = shard.bounds.find(key);
        if (found != shard.bounds.end()) return found->second;
    }
    const Interval b = mOperand->bound(box);
    std::lock_guard<std::mutex> lock(shard.mutex);
    shard.bounds.emplace(key, b);
    return b;
}

bool GridValueMemo::meets(const Box3& box, const Interval& band) const
{
    return mLeaves && mLeaves->meets(box, band);
}

void GridValueMemo::keep(bool on, std::size_t maxBytes) const
{
    mLeaves.reset();
    mConsume = false;
    mShards.reset();
    mBytes = 0;
    mMaxBytes = maxBytes;
    if (on) mShards = std::make_unique<std::array<Shard, kShards>>();
}

void GridValueMemo::keepLeaves(std::unique_ptr<KeptLeaves> leaves, std::size_t maxBytes) const
{
    if (!mShards) throw std::logic_error("GridValueMemo::keepLeaves: the memo is not keeping");
    mLeaves = std::move(leaves);
    mConsume = false;
    mMaxBytes = maxBytes;
}

bool GridValueMemo::fromLeaves(const GridBatch& batch, std::span<double> out) const
{
    if (batch.nx != 8 || batch.ny != 8 || batch.nz % 8 != 0 || batch.nz / 8 > 32) return false;
    const int count = batch.nz / 8;
    std::array<const float*, 32> leaves{};
    mLeaves->leaves(batch, std::span<const float*>(leaves.data(), std::size_t(count)));
    // The last evaluation to read them frees every leaf of the batch held, read or not, once its
    // values are taken (or not taken: the batch is then served otherwise): none is read again.
    std::uint32_t held = 0;
    for (int m = 0; m < count; ++m)
        if (leaves[std::size_t(m)]) held |= std::uint32_t(1) << m;
    const std::uint32_t read = allLeaves(count) & ~batch.unread;
    const bool served = (read & ~held) == 0;
    if (served)
        for (int m = 0; m < count; ++m)
            if (read >> m & 1u)
                putLeaf(out, batch.nz, m, [data = leaves[std::size_t(m)]](std::size_t ij) { return data + 8 * ij; });
    if (mConsume && held) mLeaves->release(batch, held);
    return served;
}

std::size_t GridValueMemo::keptBytes() const
{
    return mBytes.load();
}

std::size_t GridValueMemo::mappedBytes() const
{
    std::size_t bytes = 0;
    if (mShards)
        for (Shard& shard : *mShards) {
            std::lock_guard<std::mutex> lock(shard.mutex);
            for (const MappedBlock& b : shard.blocks) bytes += b.size();
        }
    return bytes;
}

namespace {
/// The operand's values as the memo gives them: rounded to float.
void roundToFloat(std::span<double> values)
{
    for (double& v : values) v = double(static_cast<float>(v));
}
}  // namespace

void GridValueMemo::gridValues(const GridBatch& batch, std::span<double> out) const
{
    if (batch.exact) {
        mOperand->gridValues(batch, out);
        return;
    }
    if (!mShards) {
        mOperand->gridValues(batch, out);
        roundToFloat(out.first(batch.size()));
        return;
    }
    if (mLeaves && fromLeaves(batch, out)) return;
    const Key key = keyOf(batch);
    const std::size_t hash = KeyHash{}(key);
    Shard& shard = (*mShards)[(hash >> 7) % kShards];
    const std::size_t n = batch.size();
    bool partial = false;  // kept with leaves dropped that this caller reads
    {
        std::lock_guard<std::mutex> lock(shard.mutex);
        const auto found = shard.values.find(key);
        if (found != shard.values.end()) {
            const Kept& kept = found->second;
            if (kept.dropped == 0) {
                std::copy(kept.values, kept.values + n, out.begin());
                return;
            }
            if ((kept.dropped & ~batch.unread) == 0) {
                // The leaves kept, each to its rows; the dropped ones are not read.
                for (int m = 0; m < batch.nz / 8; ++m) {
                    if (kept.dropped >> m & 1u) continue;
                    putLeaf(out, batch.nz, m, [&](std::size_t ij) { return keptRow(key, kept, m, ij); });
                }
                return;
            }
            partial = true;
        }
    }
    mOperand->gridValues(batch, out);
    roundToFloat(out.first(n));
    if (partial) return;  // the same values as the leaves kept: those stay as they are
    const std::size_t bytes = n * sizeof(float);
    if (mBytes.fetch_add(bytes) + bytes > mMaxBytes) {
        mBytes.fetch_sub(bytes);
        return;
    }
    std::lock_guard<std::mutex> lock(shard.mutex);
    if (shard.values.contains(key)) {  // kept by another thread meanwhile: the same values
        mBytes.fetch_sub(bytes);
        return;
    }
    float* kept = place(shard, n);
    std::transform(out.begin(), out.begin() + std::ptrdiff_t(n), kept, [](double v) { return static_cast<float>(v); });
    shard.values.emplace(key, Kept{kept, 0});
}

void GridValueMemo::dropOutside(Interval levels) const
{
    if (!mShards) return;
    if (mLeaves)
        mLeaves->dropIf(
            [&](const GridBatch& leaf, const float* values) { return !readAt(keyOf(leaf), values, levels); });
    // Shard by shard (each decided alone: the same batches kept for any thread count), the kept
    // values moved to the front of the shard's own blocks in the order they lie in them: each
    // batch then starts no later than it did (the same packing, of the same batches or fewer,
    // each as large or smaller), so a move never overwrites values not yet moved. Copying them
    // into fresh blocks instead wrote every kept value into pages the kernel had to clear first
    // (a 50 mm trimmed frame: 0.7 GB).
    tbb::parallel_for(0, kShards, [&](int s) {
        Shard& shard = (*mShards)[std::size_t(s)];
        std::lock_guard<std::mutex> lock(shard.mutex);
        // The blocks by address, to find which one holds a batch's values.
        std::vector<std::pair<const float*, std::size_t>> bases;
        for (std::size_t b = 0; b < shard.blocks.size(); ++b)
            bases.emplace_back(static_cast<const float*>(shard.blocks[b].data()), b);
        std::sort(bases.begin(), bases.end());
        struct Move {
            const Key* key;
            Kept* kept;
            std::uint32_t gone;  ///< a stack's leaves no longer kept (its dropped among them)
            std::size_t n;       ///< its values kept
            std::size_t block, offset;
        };
        std::vector<Move> moves;
        std::size_t dropped = 0;
        for (auto it = shard.values.begin(); it != shard.values.end();) {
            const Key& k = it->first;
            Kept& kept = it->second;
            std::uint32_t gone = 0;
            std::size_t n = std::size_t(k.nx) * std::size_t(k.ny) * std::size_t(k.nz);
            if (isStack(k)) {
                // Leaf by leaf: the stack's kept leaves that a grid in the band may read stay.
                const int leaves = k.nz / 8;
                const std::uint32_t all = allLeaves(leaves);
                gone = unreadLeaves(k, kept, levels);
                dropped += std::size_t(std::popcount(gone) - std::popcount(kept.dropped)) * 512 * sizeof(float);
                if (gone == all) {
                    it = shard.values.erase(it);
                    continue;
                }
                n = std::size_t(leaves - std::popcount(gone)) * 512;
            } else if (!readAt(k, kept.values, levels)) {
                dropped += n * sizeof(float);
                it = shard.values.erase(it);
                continue;
            }
            const auto holder =
                std::prev(std::upper_bound(bases.begin(), bases.end(), std::make_pair(kept.values, ~std::size_t(0))));
            moves.push_back({&k, &kept, gone, n, holder->second, std::size_t(kept.values - holder->first)});
            ++it;
        }
        std::sort(moves.begin(), moves.end(), [](const Move& a, const Move& b) {
            return std::tie(a.block, a.offset) < std::tie(b.block, b.offset);
        });
        std::size_t block = 0;
        float* next = shard.blocks.empty() ? nullptr : static_cast<float*>(shard.blocks[0].data());
        std::size_t left = shard.blocks.empty() ? 0 : shard.blocks[0].size() / sizeof(float);
        std::vector<float> gathered;  // a stack's rows as it will hold them, when that changes
        for (const Move& m : moves) {
            const Key& k = *m.key;
            Kept& kept = *m.kept;
            const std::size_t n = m.n;
            if (left < n) {  // the next block: one the batch lay in or before (never past the last)
                ++block;
                next = static_cast<float*>(shard.blocks[block].data());
                left = shard.blocks[block].size() / sizeof(float);
            }
            float* to = next;
            next += n;
            left -= n;
            if (isStack(k) && m.gone != kept.dropped) {
                // Its kept leaves' rows in turn: gathered first, as the batch's own layout
                // interleaves them (moved in place, a row would overwrite one not yet read).
                gathered.resize(n);
                float* at = gathered.data();
                for (int leaf = 0; leaf < k.nz / 8; ++leaf)
                    if (!(m.gone >> leaf & 1u))
                        for (std::size_t ij = 0; ij < 64; ++ij) {
                            const float* row = keptRow(k, kept, leaf, ij);
                            at = std::copy(row, row + 8, at);
                        }
                std::copy(gathered.begin(), gathered.end(), to);
                kept.dropped = m.gone;
            } else if (to != kept.values) {
                std::memmove(to, kept.values, n * sizeof(float));
            }
            kept.values = to;
        }
        // The blocks past the last one used go back to the system.
        shard.blocks.resize(moves.empty() ? 0 : block + 1);
        shard.next = moves.empty() ? nullptr : next;
        shard.left = moves.empty() ? 0 : left;
        mBytes.fetch_sub(dropped);
    });
}

std::uint32_t GridValueMemo::unreadLeaves(const Key& k, const Kept& kept, Interval levels) const
{
    std::uint32_t gone = kept.dropped;
    for (int m = 0; m < k.nz / 8; ++m) {
        if (kept.dropped >> m & 1u) continue;
        float leaf[512];
        for (std::size_t ij = 0; ij < 64; ++ij) {
            const float* row = keptRow(k, kept, m, ij);
            std::copy(row, row + 8, leaf + 8 * ij);
        }
        // The leaf's own batch: its first point k = 8m of the stack.
        Key leafKey = k;
        leafKey.oz = k.oz + (8 * m) * k.sz;
        leafKey.nz = 8;
        if (!readAt(leafKey, leaf, levels)) gone |= std::uint32_t(1) << m;
    }
    return gone;
}

bool GridValueMemo::readAt(const Key& k, const float* values, Interval levels) const
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

float* GridValueMemo::place(Shard& shard, std::size_t n)
{
    if (shard.left < n) {
        const std::size_t size = std::max(kBlockValues, n);
        shard.blocks.emplace_back(size * sizeof(float));
        shard.next = static_cast<float*>(shard.blocks.back().data());
        shard.left = size;
    }
    float* at = shard.next;
    shard.next += n;
    shard.left -= n;
    return at;
}

}  // namespace voxlat
