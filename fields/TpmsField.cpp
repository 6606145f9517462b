#include "fields/TpmsField.h"

#include <array>
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

void TpmsField::values(std::span<const Vec3d> points, std::span<double> out) const
{
    for (std::size_t n = 0; n < points.size(); ++n) {
        const Vec3d& p = points[n];
        out[n] = tpmsEquation(mType, trigTerms(mWave[0] * p[0]), trigTerms(mWave[1] * p[1]),
                              trigTerms(mWave[2] * p[2]));
    }
}

void TpmsField::gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const
{
    for (std::size_t n = 0; n < points.size(); ++n) {
        const Vec3d& p = points[n];
        const Dual3 x(mWave[0] * p[0], mWave[0], 0, 0);
        const Dual3 y(mWave[1] * p[1], 0, mWave[1], 0);
        const Dual3 z(mWave[2] * p[2], 0, 0, mWave[2]);
        const Dual3 f = tpmsEquation(mType, trigTerms(x), trigTerms(y), trigTerms(z));
        out[n] = f.v;
        grad[n] = Vec3d(f.d[0], f.d[1], f.d[2]);
    }
}

void TpmsField::gridValues(const GridBatch& batch, std::span<double> out) const
{
    constexpr int kMax = 64;
    if (batch.nx > kMax || batch.ny > kMax || batch.nz > kMax) {
        FieldNode::gridValues(batch, out);
        return;
    }
    std::array<TrigTerms<double>, kMax> tx, ty, tz;
    for (int i = 0; i < batch.nx; ++i) tx[i] = trigTerms(mWave[0] * (batch.origin[0] + i * batch.spacing[0]));
    for (int j = 0; j < batch.ny; ++j) ty[j] = trigTerms(mWave[1] * (batch.origin[1] + j * batch.spacing[1]));
    for (int k = 0; k < batch.nz; ++k) tz[k] = trigTerms(mWave[2] * (batch.origin[2] + k * batch.spacing[2]));
    std::size_t n = 0;
    for (int i = 0; i < batch.nx; ++i)
        for (int j = 0; j < batch.ny; ++j)
            for (int k = 0; k < batch.nz; ++k) out[n++] = tpmsEquation(mType, tx[i], ty[j], tz[k]);
}

void TpmsField::gridGradients(const GridBatch& batch, std::span<double> out, std::span<Vec3d> grad) const
{
    constexpr int kMax = 64;
    if (batch.nx > kMax || batch.ny > kMax || batch.nz > kMax) {
        FieldNode::gridGradients(batch, out, grad);
        return;
    }
    std::array<TrigTerms<Dual3>, kMax> tx, ty, tz;
    for (int i = 0; i < batch.nx; ++i)
        tx[i] = trigTerms(Dual3(mWave[0] * (batch.origin[0] + i * batch.spacing[0]), mWave[0], 0, 0));
    for (int j = 0; j < batch.ny; ++j)
        ty[j] = trigTerms(Dual3(mWave[1] * (batch.origin[1] + j * batch.spacing[1]), 0, mWave[1], 0));
    for (int k = 0; k < batch.nz; ++k)
        tz[k] = trigTerms(Dual3(mWave[2] * (batch.origin[2] + k * batch.spacing[2]), 0, 0, mWave[2]));
    std::size_t n = 0;
    for (int i = 0; i < batch.nx; ++i)
        for (int j = 0; j < batch.ny; ++j)
            for (int k = 0; k < batch.nz; ++k, ++n) {
                const Dual3 f = tpmsEquation(mType, tx[i], ty[j], tz[k]);
                out[n] = f.v;
                grad[n] = Vec3d(f.d[0], f.d[1], f.d[2]);
            }
}

Interval TpmsField::bound(const Box3& box) const
{
    const Interval x(mWave[0] * box.min[0], mWave[0] * box.max[0]);
    const Interval y(mWave[1] * box.min[1], mWave[1] * box.max[1]);
    const Interval z(mWave[2] * box.min[2], mWave[2] * box.max[2]);
    return tpmsEquation(mType, trigTerms(x), trigTerms(y), trigTerms(z));
}

}  // namespace voxlat
