#include "fields/tpms/TpmsField.h"

#include "fields/core/SinCos.h"
#include "fields/core/SolidSide.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <numbers>
#include <stdexcept>

namespace voxlat {

namespace {
struct NamedType {
    std::string_view name;
    TpmsType type;
    Interval levels;
};
constexpr std::array<NamedType, 9> kTypes{{
    {"gyroid", TpmsType::Gyroid, {-1.5, 1.5}},
    {"schwarz-p", TpmsType::SchwarzP, {-3.0, 3.0}},
    {"schwarz-d", TpmsType::SchwarzD, {-1.414, 1.414}},
    {"iwp", TpmsType::IWP, {-5.0, 3.0}},
    {"neovius", TpmsType::Neovius, {-13.0, 13.0}},
    {"fischer-koch-s", TpmsType::FischerKochS, {-1.414, 1.414}},
    {"lidinoid", TpmsType::Lidinoid, {-2.7, 2.3}},
    {"split-p", TpmsType::SplitP, {-1.8, 1.81}},
    {"frd", TpmsType::FRD, {-10.0, 6.0}},
}};
}  // namespace

std::string_view tpmsName(TpmsType type)
{
    for (const auto& t : kTypes)
        if (t.type == type) return t.name;
    return "?";
}

bool parseTpmsType(std::string_view name, TpmsType& type)
{
    for (const auto& t : kTypes)
        if (t.name == name) {
            type = t.type;
            return true;
        }
    return false;
}

std::vector<std::string> tpmsNames()
{
    std::vector<std::string> names;
    for (const auto& t : kTypes) names.emplace_back(t.name);
    return names;
}

Interval tpmsLevelRange(TpmsType type)
{
    for (const auto& t : kTypes)
        if (t.type == type) return t.levels;
    return {};
}

TpmsField::TpmsField(TpmsType type, const Vec3d& cellSize) : mType(type), mCell(cellSize)
{
    for (int a = 0; a < 3; ++a) {
        if (!(cellSize[a] > 0.0)) throw std::invalid_argument("TPMS cell size must be positive");
        mWave[a] = 2.0 * std::numbers::pi / cellSize[a];
    }
}

namespace {
/// Points per batch of sines and cosines in values() and gradients().
constexpr std::size_t kTrigChunk = 128;
/// The scaled coordinates of up to kTrigChunk points and their sines and cosines, per axis.
struct PointTrig {
    double angle[3][kTrigChunk], s[3][kTrigChunk], c[3][kTrigChunk];
    void compute(std::span<const Vec3d> points, std::size_t begin, std::size_t n, const double* wave)
    {
        for (int a = 0; a < 3; ++a) {
            for (std::size_t k = 0; k < n; ++k) angle[a][k] = wave[a] * points[begin + k][a];
            sinCosBatch(angle[a], s[a], c[a], n);
        }
    }
};
}  // namespace

void TpmsField::values(std::span<const Vec3d> points, std::span<double> out) const
{
    PointTrig t;
    for (std::size_t begin = 0; begin < points.size(); begin += kTrigChunk) {
        const std::size_t n = std::min(kTrigChunk, points.size() - begin);
        t.compute(points, begin, n, mWave.asPointer());
        for (std::size_t k = 0; k < n; ++k) {
            out[begin + k] = tpmsEquation(mType, trigTermsFrom(t.s[0][k], t.c[0][k]),
                                          trigTermsFrom(t.s[1][k], t.c[1][k]), trigTermsFrom(t.s[2][k], t.c[2][k]));
        }
    }
}

void TpmsField::gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const
{
    PointTrig t;
    for (std::size_t begin = 0; begin < points.size(); begin += kTrigChunk) {
        const std::size_t n = std::min(kTrigChunk, points.size() - begin);
        t.compute(points, begin, n, mWave.asPointer());
        if (mType == TpmsType::Gyroid) {
            // The gyroid written out: the dual numbers' products and sums without their terms
            // that are zero, in their order (the same doubles; a third of the refinement's
            // evaluation went to the zeros).
            const double wx = mWave[0], wy = mWave[1], wz = mWave[2];
            for (std::size_t k = 0; k < n; ++k) {
                const double sx = t.s[0][k], cx = t.c[0][k], sy = t.s[1][k], cy = t.c[1][k], sz = t.s[2][k],
                             cz = t.c[2][k];
                out[begin + k] = sx * cy + sy * cz + sz * cx;
                grad[begin + k] = Vec3d(cx * wx * cy + sz * (-sx * wx), sx * (-sy * wy) + cy * wy * cz,
                                        sy * (-sz * wz) + cz * wz * cx);
            }
            continue;
        }
        for (std::size_t k = 0; k < n; ++k) {
            const Dual3 x(t.angle[0][k], mWave[0], 0, 0), y(t.angle[1][k], 0, mWave[1], 0),
                z(t.angle[2][k], 0, 0, mWave[2]);
            const Dual3 f =
                tpmsEquation(mType, trigTermsFrom(t.s[0][k], t.c[0][k], x), trigTermsFrom(t.s[1][k], t.c[1][k], y),
                             trigTermsFrom(t.s[2][k], t.c[2][k], z));
            out[begin + k] = f.v;
            grad[begin + k] = Vec3d(f.d[0], f.d[1], f.d[2]);
        }
    }
}

namespace {

/// trigTerms of wave * (origin + i * spacing), i < n: sin and cos (sinCosBatch) at every eighth
/// angle and rotated from it by exact offsets in between (angle addition, within a few ulp), so a
/// slicer block's 66 angles per axis cost 9 + 7 sines and cosines instead of 66.
void axisTerms(double wave, double origin, double spacing, int n, TrigTerms<double>* out)
{
    constexpr int kStride = 8;
    if (n < 2 * kStride) {
        // As the point path computes them (sinCosBatch of the same angles): the same doubles.
        double angle[2 * kStride] = {}, s[2 * kStride], c[2 * kStride];
        for (int i = 0; i < n; ++i) angle[i] = wave * (origin + i * spacing);
        sinCosBatch(angle, s, c, std::size_t(n));
        for (int i = 0; i < n; ++i) out[i] = trigTermsFrom(s[i], c[i]);
        return;
    }
    // The offsets' sines and cosines depend on the spacing only: kept per thread for the next
    // call (a slicer asks for the same spacing block after block).
    struct Offsets {
        double wave = 0.0, spacing = 0.0, so[kStride] = {}, co[kStride] = {};
    };
    thread_local Offsets offsets;
    if (offsets.wave != wave || offsets.spacing != spacing || offsets.co[0] != 1.0) {
        double angle[kStride];
        for (int k = 0; k < kStride; ++k) angle[k] = wave * (k * spacing);
        sinCosBatch(angle, offsets.so, offsets.co, kStride);
        offsets.wave = wave;
        offsets.spacing = spacing;
    }
    const double* so = offsets.so;
    const double* co = offsets.co;
    // Every eighth angle's sine and cosine in batches, then the rotations between them.
    constexpr int kBases = 32;
    for (int first = 0; first < n; first += kBases * kStride) {
        const int bases = std::min(kBases, (n - first + kStride - 1) / kStride);
        double angle[kBases], sines[kBases], cosines[kBases];
        for (int b = 0; b < bases; ++b) angle[b] = wave * (origin + (first + b * kStride) * spacing);
        sinCosBatch(angle, sines, cosines, std::size_t(bases));
        for (int b = 0; b < bases; ++b) {
            const int i = first + b * kStride;
            const double sb = sines[b], cb = cosines[b];
            out[i] = trigTermsFrom(sb, cb);
            for (int k = 1; k < kStride && i + k < n; ++k)
                out[i + k] = trigTermsFrom(sb * co[k] + cb * so[k], cb * co[k] - sb * so[k]);
        }
    }
}

/// axisTerms through a per-thread cache, by axis (0 x, 1 y, 2 z): a slicer's blocks along a row
/// share their y terms, a whole layer its z term, and every layer the x terms of the same few
/// block columns, so most calls find them here (x keeps 32 runs by their origin, y the last one,
/// z 16 by their origin: the sparse evaluator's leaves run through the 16 z columns of a 128^3
/// block for each y). The terms depend on the arguments only, never on which thread made them.
const TrigTerms<double>* cachedAxisTerms(int axis, double wave, double origin, double spacing, int n,
                                         TrigTerms<double>* scratch)
{
    constexpr int kMaxTerms = 128, kXRuns = 32, kZRuns = 16;
    struct Run {
        double wave = 0.0, origin = 0.0, spacing = 0.0;
        int n = -1;
        TrigTerms<double> terms[kMaxTerms];
    };
    thread_local std::array<Run, kXRuns + 1 + kZRuns> runs;
    if (n > kMaxTerms) {
        axisTerms(wave, origin, spacing, n, scratch);
        return scratch;
    }
    std::size_t slot = kXRuns;  // y
    if (axis != 1) {
        std::uint64_t bits;
        std::memcpy(&bits, &origin, sizeof bits);
        const std::uint64_t hash = bits * 0x9E3779B97F4A7C15ull;
        slot = axis == 0 ? std::size_t(hash >> 59)                // 5 bits: one of kXRuns
                         : kXRuns + 1 + std::size_t(hash >> 60);  // 4 bits: one of kZRuns
    }
    Run& run = runs[slot];
    if (run.n != n || run.wave != wave || run.origin != origin || run.spacing != spacing) {
        axisTerms(wave, origin, spacing, n, run.terms);
        run.wave = wave;
        run.origin = origin;
        run.spacing = spacing;
        run.n = n;
    }
    return run.terms;
}

/// A solid's level (LevelSolid::gridValues's expressions, per value), with its kind for
/// gyroidSlice.
struct NoLevel {
    static constexpr int kKind = 0;
    double level = 0.0;
    double operator()(double v) const { return v; }
};
struct BelowLevel {
    static constexpr int kKind = 1;
    double level;
    double operator()(double v) const { return v - level; }
};
struct BandLevel {
    static constexpr int kKind = 2;
    double level;
    double operator()(double v) const { return std::abs(v) - level; }
};
struct AboveLevel {
    static constexpr int kKind = 3;
    double level;
    double operator()(double v) const { return level - v; }
};

/// The gyroid on one slice (tpmsEquation's x.s y.c + y.s z.c + z.s x.c, the same operations in
/// the same order) with a level of kind @a kind (0 none, then BelowLevel, BandLevel, AboveLevel),
/// @a nx columns of @a ny values. The slicer's hot loop: built for AVX2 too (four doubles a
/// vector) and picked at load time where the CPU has it; no FMA either way, so the same doubles.
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
__attribute__((target_clones("avx2", "default")))
#endif
void gyroidSlice(const TrigTerms<double>* tx, int nx, const double* ys, const double* yc, int ny, double zs,
                 double zc, int kind, double level, double* out)
{
    for (int i = 0; i < nx; ++i, out += ny) {
        const double xs = tx[i].s, xc = tx[i].c;
        switch (kind) {
            case 0:
                for (int j = 0; j < ny; ++j) out[j] = xs * yc[j] + ys[j] * zc + zs * xc;
                break;
            case 1:
                for (int j = 0; j < ny; ++j) out[j] = (xs * yc[j] + ys[j] * zc + zs * xc) - level;
                break;
            case 2:
                for (int j = 0; j < ny; ++j) out[j] = std::abs(xs * yc[j] + ys[j] * zc + zs * xc) - level;
                break;
            default:
                for (int j = 0; j < ny; ++j) out[j] = level - (xs * yc[j] + ys[j] * zc + zs * xc);
                break;
        }
    }
}

/// A box of terms: @a nx x @a ny x @a nz values (z innermost, its terms as four arrays) into out.
struct BoxTerms {
    const TrigTerms<double>* tx;
    int nx;
    const TrigTerms<double>* ty;
    int ny;
    const double *zs, *zc, *zs2, *zc2;
    int nz;
    double* out;
};

/// One box of surface @a kType, each value through @a map (restrict parameters: GCC vectorises
/// the rows without tests of overlap).
template <TpmsType kType, class Map>
[[gnu::always_inline]] inline void tpmsRows(const TrigTerms<double>* __restrict tx, int nx,
                                            const TrigTerms<double>* __restrict ty, int ny, const double* __restrict zs,
                                            const double* __restrict zc, const double* __restrict zs2,
                                            const double* __restrict zc2, int nz, const Map& map,
                                            double* __restrict out)
{
    for (int i = 0; i < nx; ++i)
        for (int j = 0; j < ny; ++j, out += nz)
            for (int k = 0; k < nz; ++k)
                out[k] = map(tpmsEquation(kType, tx[i], ty[j], TrigTerms<double>{zs[k], zc[k], zs2[k], zc2[k]}));
}
template <TpmsType kType, class Map>
[[gnu::always_inline]] inline void tpmsBoxOf(const BoxTerms& b, const Map& map)
{
    tpmsRows<kType>(b.tx, b.nx, b.ty, b.ny, b.zs, b.zc, b.zs2, b.zc2, b.nz, map, b.out);
}

template <TpmsType kType>
[[gnu::always_inline]] inline void tpmsBoxAtLevel(int kind, double level, const BoxTerms& box)
{
    switch (kind) {
        case 0:
            return tpmsBoxOf<kType>(box, NoLevel{level});
        case 1:
            return tpmsBoxOf<kType>(box, BelowLevel{level});
        case 2:
            return tpmsBoxOf<kType>(box, BandLevel{level});
        default:
            return tpmsBoxOf<kType>(box, AboveLevel{level});
    }
}

/// A box of any of the nine surfaces with a level of kind @a kind (as gyroidSlice): the mesher's
/// and the density solve's leaves. Built for AVX2 too (four doubles a vector) and picked at load
/// time; no FMA either way, so the same doubles as the scalar expressions.
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
__attribute__((target_clones("avx2", "default")))
#endif
void tpmsBox(TpmsType type, int kind, double level, const BoxTerms& box)
{
    // clang-format off
    switch (type) {
    case TpmsType::Gyroid: return tpmsBoxAtLevel<TpmsType::Gyroid>(kind, level, box);
    case TpmsType::SchwarzP: return tpmsBoxAtLevel<TpmsType::SchwarzP>(kind, level, box);
    case TpmsType::SchwarzD: return tpmsBoxAtLevel<TpmsType::SchwarzD>(kind, level, box);
    case TpmsType::IWP: return tpmsBoxAtLevel<TpmsType::IWP>(kind, level, box);
    case TpmsType::Neovius: return tpmsBoxAtLevel<TpmsType::Neovius>(kind, level, box);
    case TpmsType::FischerKochS: return tpmsBoxAtLevel<TpmsType::FischerKochS>(kind, level, box);
    case TpmsType::Lidinoid: return tpmsBoxAtLevel<TpmsType::Lidinoid>(kind, level, box);
    case TpmsType::SplitP: return tpmsBoxAtLevel<TpmsType::SplitP>(kind, level, box);
    case TpmsType::FRD: return tpmsBoxAtLevel<TpmsType::FRD>(kind, level, box);
    }
    // clang-format on
}
}  // namespace

void TpmsField::gridValues(const GridBatch& batch, std::span<double> out) const
{
    gridValuesMapped(batch, out, NoLevel{});
}

void TpmsField::gridValuesAtLevel(const GridBatch& batch, std::span<double> out, SolidSide side, double level) const
{
    switch (side) {
        case SolidSide::Below:
            gridValuesMapped(batch, out, BelowLevel{level});
            return;
        case SolidSide::Band:
            gridValuesMapped(batch, out, BandLevel{level});
            return;
        case SolidSide::Above:
            gridValuesMapped(batch, out, AboveLevel{level});
            return;
    }
}

template <class Map>
void TpmsField::gridValuesMapped(const GridBatch& batch, std::span<double> out, const Map& map) const
{
    constexpr int kMax = 128;  // a slicer block with its halo is 66 wide
    if (batch.nx > kMax || batch.ny > kMax || batch.nz > kMax) {
        FieldNode::gridValues(batch, out);
        for (double& v : out) v = map(v);
        return;
    }
    std::array<TrigTerms<double>, kMax> scratch;
    const TrigTerms<double>* tx =
        cachedAxisTerms(0, mWave[0], batch.origin[0], batch.spacing[0], batch.nx, scratch.data());
    const TrigTerms<double>* ty =
        cachedAxisTerms(1, mWave[1], batch.origin[1], batch.spacing[1], batch.ny, scratch.data());
    const TrigTerms<double>* tz =
        cachedAxisTerms(2, mWave[2], batch.origin[2], batch.spacing[2], batch.nz, scratch.data());
    // The surface type is fixed per call: one loop nest per type (tpmsBox, and the slices below)
    // lets the compiler inline the equation (no switch per point); a single z (slices) drops the
    // innermost loop.
    // The innermost axis's terms as four arrays (structure of arrays), so the inner loop reads
    // each term contiguously and vectorises.
    const bool slices = batch.nz == 1;
    const TrigTerms<double>* inner = slices ? ty : tz;
    const int innerCount = slices ? batch.ny : batch.nz;
    std::array<double, kMax> is, ic, is2, ic2;
    for (int k = 0; k < innerCount; ++k)
        is[k] = inner[k].s, ic[k] = inner[k].c, is2[k] = inner[k].s2, ic2[k] = inner[k].c2;
    if (slices && mType == TpmsType::Gyroid) {
        gyroidSlice(tx, batch.nx, is.data(), ic.data(), innerCount, tz[0].s, tz[0].c, Map::kKind, map.level,
                    out.data());
        return;
    }
    if (!slices) {
        tpmsBox(
            mType, Map::kKind, map.level,
            BoxTerms{tx, batch.nx, ty, batch.ny, is.data(), ic.data(), is2.data(), ic2.data(), innerCount, out.data()});
        return;
    }
    auto fill = [&]<TpmsType kType>() {
        double* o = out.data();
        for (int i = 0; i < batch.nx; ++i, o += innerCount)
            for (int j = 0; j < innerCount; ++j)
                o[j] = map(tpmsEquation(kType, tx[i], TrigTerms<double>{is[j], ic[j], is2[j], ic2[j]}, tz[0]));
    };
    // clang-format misreads this switch after the template lambda and would spread it over 27 lines.
    // clang-format off
    switch (mType) {
    case TpmsType::Gyroid: fill.template operator()<TpmsType::Gyroid>(); break;
    case TpmsType::SchwarzP: fill.template operator()<TpmsType::SchwarzP>(); break;
    case TpmsType::SchwarzD: fill.template operator()<TpmsType::SchwarzD>(); break;
    case TpmsType::IWP: fill.template operator()<TpmsType::IWP>(); break;
    case TpmsType::Neovius: fill.template operator()<TpmsType::Neovius>(); break;
    case TpmsType::FischerKochS: fill.template operator()<TpmsType::FischerKochS>(); break;
    case TpmsType::Lidinoid: fill.template operator()<TpmsType::Lidinoid>(); break;
    case TpmsType::SplitP: fill.template operator()<TpmsType::SplitP>(); break;
    case TpmsType::FRD: fill.template operator()<TpmsType::FRD>(); break;
    }
    // clang-format on
}

void TpmsField::gridGradients(const GridBatch& batch, std::span<double> out, std::span<Vec3d> grad) const
{
    constexpr int kMax = 128;  // a slicer block with its halo is 66 wide
    if (batch.nx > kMax || batch.ny > kMax || batch.nz > kMax) {
        FieldNode::gridGradients(batch, out, grad);
        return;
    }
    std::array<TrigTerms<Dual3>, kMax> terms[3];
    const int count[3] = {batch.nx, batch.ny, batch.nz};
    for (int a = 0; a < 3; ++a) {
        double angle[kMax], s[kMax], c[kMax];
        for (int i = 0; i < count[a]; ++i) angle[i] = mWave[a] * (batch.origin[a] + i * batch.spacing[a]);
        sinCosBatch(angle, s, c, std::size_t(count[a]));
        for (int i = 0; i < count[a]; ++i) {
            Dual3 x(angle[i]);
            x.d[a] = mWave[a];
            terms[a][i] = trigTermsFrom(s[i], c[i], x);
        }
    }
    const auto &tx = terms[0], &ty = terms[1], &tz = terms[2];
    std::size_t n = 0;
    for (int i = 0; i < batch.nx; ++i)
        for (int j = 0; j < batch.ny; ++j)
            for (int k = 0; k < batch.nz; ++k, ++n) {
                const Dual3 f = tpmsEquation(mType, tx[i], ty[j], tz[k]);
                out[n] = f.v;
                grad[n] = Vec3d(f.d[0], f.d[1], f.d[2]);
            }
}

namespace {
// sin and cos of small angles (|a| <= 0.5): Taylor polynomials in Horner form, error below 1e-15.
// Branch-free, so the loops over a leaf's angles vectorise; larger angles are redone with libm.
constexpr double kSmallAngle = 0.5;
inline double smallSin(double a)
{
    constexpr double s3 = -1.0 / 6, s5 = 1.0 / 120, s7 = -1.0 / 5040, s9 = 1.0 / 362880, s11 = -1.0 / 39916800,
                     s13 = 1.0 / 6227020800.0;
    const double a2 = a * a;
    return a + a * a2 * (s3 + a2 * (s5 + a2 * (s7 + a2 * (s9 + a2 * (s11 + a2 * s13)))));
}
inline double smallCos(double a)
{
    constexpr double c2 = -1.0 / 2, c4 = 1.0 / 24, c6 = -1.0 / 720, c8 = 1.0 / 40320, c10 = -1.0 / 3628800,
                     c12 = 1.0 / 479001600.0, c14 = -1.0 / 87178291200.0;
    const double a2 = a * a;
    return 1.0 + a2 * (c2 + a2 * (c4 + a2 * (c6 + a2 * (c8 + a2 * (c10 + a2 * (c12 + a2 * c14))))));
}

}  // namespace

void TpmsField::gridValuesShifted(const GridBatch& batch, std::span<const Vec3d> shift, std::span<double> plus,
                                  std::span<double> minus) const
{
    constexpr int kMax = 128;  // a slicer block with its halo is 66 wide
    if (batch.nx > kMax || batch.ny > kMax || batch.nz > kMax) {
        FieldNode::gridValuesShifted(batch, shift, plus, minus);
        return;
    }
    std::array<double, kMax> base[3][2];  // sin, cos of the unshifted angle per axis coordinate
    const int count[3] = {batch.nx, batch.ny, batch.nz};
    for (int a = 0; a < 3; ++a) {
        double angle[kMax];
        for (int i = 0; i < count[a]; ++i) angle[i] = mWave[a] * (batch.origin[a] + i * batch.spacing[a]);
        sinCosBatch(angle, base[a][0].data(), base[a][1].data(), std::size_t(count[a]));
    }
    // Shift angles, their sines and cosines, axis by axis (structure of arrays).
    const std::size_t n = batch.size();
    std::vector<double> angle(3 * n), sinA(3 * n), cosA(3 * n);
    for (int a = 0; a < 3; ++a) {
        double* ang = angle.data() + a * n;
        for (std::size_t p = 0; p < n; ++p) ang[p] = mWave[a] * shift[p][a];
        double* sa = sinA.data() + a * n;
        double* ca = cosA.data() + a * n;
        for (std::size_t p = 0; p < n; ++p) {
            sa[p] = smallSin(ang[p]);
            ca[p] = smallCos(ang[p]);
        }
        for (std::size_t p = 0; p < n; ++p)
            if (std::abs(ang[p]) > kSmallAngle) [[unlikely]] {
                sa[p] = std::sin(ang[p]);
                ca[p] = std::cos(ang[p]);
            }
    }
    std::size_t p = 0;
    for (int i = 0; i < batch.nx; ++i)
        for (int j = 0; j < batch.ny; ++j)
            for (int k = 0; k < batch.nz; ++k, ++p) {
                const int index[3] = {i, j, k};
                TrigTerms<double> up[3], down[3];
                for (int a = 0; a < 3; ++a) {
                    const double s = sinA[a * n + p], c = cosA[a * n + p];
                    const double sb = base[a][0][index[a]], cb = base[a][1][index[a]];
                    up[a] = trigTermsFrom(sb * c + cb * s, cb * c - sb * s);
                    down[a] = trigTermsFrom(sb * c - cb * s, cb * c + sb * s);
                }
                plus[p] = tpmsEquation(mType, up[0], up[1], up[2]);
                minus[p] = tpmsEquation(mType, down[0], down[1], down[2]);
            }
}

Interval TpmsField::bound(const Box3& box) const
{
    const Interval x(mWave[0] * box.min[0], mWave[0] * box.max[0]);
    const Interval y(mWave[1] * box.min[1], mWave[1] * box.max[1]);
    const Interval z(mWave[2] * box.min[2], mWave[2] * box.max[2]);
    // The double-angle terms only where the equation uses them: each interval cos costs two libm
    // calls, and the slicer and the sparse evaluator ask for bounds of many small boxes.
    const bool doubleAngles = mType != TpmsType::Gyroid && mType != TpmsType::SchwarzP && mType != TpmsType::SchwarzD &&
                              mType != TpmsType::Neovius;
    auto terms = [&](Interval a) {
        if (doubleAngles) return trigTerms(a);
        const Interval unused(0.0, 0.0);
        return TrigTerms<Interval>{sin(a), cos(a), unused, unused};
    };
    // The sparse evaluator bounds every leaf of a 128^3 block: 16 distinct intervals per axis,
    // each asked for 256 times. A small per-thread cache by interval (the terms depend on it
    // alone) leaves about one libm call in ten.
    struct Entry {
        Interval key{1.0, 0.0};  // empty: matches nothing
        bool doubleAngles = false;
        TrigTerms<Interval> terms;
    };
    thread_local std::array<Entry, 64> cache;
    auto cachedTerms = [&](Interval a) -> TrigTerms<Interval> {
        std::uint64_t lo, hi;
        std::memcpy(&lo, &a.lo, sizeof lo);
        std::memcpy(&hi, &a.hi, sizeof hi);
        Entry& e = cache[std::size_t(((lo ^ (hi * 0xC2B2AE3D27D4EB4Full)) * 0x9E3779B97F4A7C15ull) >> 58)];
        if (e.key.lo != a.lo || e.key.hi != a.hi || e.doubleAngles != doubleAngles) {
            e.key = a;
            e.doubleAngles = doubleAngles;
            e.terms = terms(a);
        }
        return e.terms;
    };
    return tpmsEquation(mType, cachedTerms(x), cachedTerms(y), cachedTerms(z));
}

}  // namespace voxlat
