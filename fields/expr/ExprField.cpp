#include "fields/expr/ExprField.h"

#include "fields/core/Scratch.h"

#include <stdexcept>

namespace voxlat {

ExprField::ExprField(std::shared_ptr<const ExprProgram> program, std::vector<FieldPtr> inputs)
    : mProgram(std::move(program)), mInputs(std::move(inputs))
{
    if (int(mInputs.size()) < mProgram->inputCount())
        throw std::invalid_argument("ExprField: the equation needs more input fields than were given");
}

void ExprField::values(std::span<const Vec3d> points, std::span<double> out) const
{
    const std::size_t m = mInputs.size();
    forEachChunk(points.size(), [&](std::size_t begin, std::size_t count) {
        // Input values first (they may be equations themselves: deeper scratch levels).
        ScratchLease scratch(m * count + m);
        const double** inputs = reinterpret_cast<const double**>(scratch.data());
        double* buffer = scratch.data() + m;
        for (std::size_t i = 0; i < m; ++i) {
            mInputs[i]->values(points.subspan(begin, count), std::span<double>(buffer + i * count, count));
            inputs[i] = buffer + i * count;
        }
        mProgram->values(points.subspan(begin, count), inputs, out.subspan(begin, count));
    });
}

void ExprField::gridValues(const GridBatch& batch, std::span<double> out) const
{
    const std::size_t n = batch.size();
    if (n > kBatchSize) {
        FieldNode::gridValues(batch, out);  // expands into points, evaluated in chunks
        return;
    }
    const std::size_t m = mInputs.size();
    ScratchLease scratch(m * n + m);
    const double** inputs = reinterpret_cast<const double**>(scratch.data());
    double* buffer = scratch.data() + m;
    for (std::size_t i = 0; i < m; ++i) {
        mInputs[i]->gridValues(batch, std::span<double>(buffer + i * n, n));
        inputs[i] = buffer + i * n;
    }
    mProgram->gridValues(batch, inputs, out.first(n));
}

void ExprField::gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const
{
    const std::size_t m = mInputs.size();
    constexpr std::size_t kD = sizeof(Dual3) / sizeof(double);
    forEachChunk(points.size(), [&](std::size_t begin, std::size_t count) {
        // Layout: m input pointers, m*count input duals, count result duals, then scratch for
        // one input's values and gradients.
        const std::size_t pointerDoubles = m;
        ScratchLease scratch(pointerDoubles + (m + 1) * count * kD + count * 4);
        const Dual3** inputs = reinterpret_cast<const Dual3**>(scratch.data());
        Dual3* duals = reinterpret_cast<Dual3*>(scratch.data() + pointerDoubles);
        Dual3* result = duals + m * count;
        double* values = reinterpret_cast<double*>(result + count);
        Vec3d* grads = reinterpret_cast<Vec3d*>(values + count);
        const auto pts = points.subspan(begin, count);
        for (std::size_t i = 0; i < m; ++i) {
            mInputs[i]->gradients(pts, std::span<double>(values, count), std::span<Vec3d>(grads, count));
            Dual3* d = duals + i * count;
            for (std::size_t n = 0; n < count; ++n) d[n] = Dual3(values[n], grads[n][0], grads[n][1], grads[n][2]);
            inputs[i] = d;
        }
        mProgram->gradients(pts, inputs, std::span<Dual3>(result, count));
        for (std::size_t n = 0; n < count; ++n) {
            out[begin + n] = result[n].v;
            grad[begin + n] = Vec3d(result[n].d[0], result[n].d[1], result[n].d[2]);
        }
    });
}

Interval ExprField::bound(const Box3& box) const
{
    const std::size_t m = mInputs.size();
    ScratchLease scratch(2 * m + 2);
    Interval* inputs = scratch.as<Interval>();
    for (std::size_t i = 0; i < m; ++i) inputs[i] = mInputs[i]->bound(box);
    return mProgram->bound(box, inputs);
}

}  // namespace voxlat
