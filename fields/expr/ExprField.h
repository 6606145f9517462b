/// @file ExprField.h
/// @brief A field given by a user equation over x, y, z and other fields.
#pragma once

#include "fields/expr/Expression.h"

#include <vector>

namespace voxlat {

/// value = program(x, y, z, inputs...). Values on grid blocks share per-axis work (see
/// ExprProgram), gradients come from forward-mode differentiation through the program (and the
/// inputs' own analytic gradients), bounds from interval evaluation over the inputs' bounds.
class ExprField final : public FieldNode {
public:
    /// @a inputs are the fields named in the equation, in the order of their input indices.
    ExprField(std::shared_ptr<const ExprProgram> program, std::vector<FieldPtr> inputs);

    void values(std::span<const Vec3d> points, std::span<double> out) const override;
    void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const override;
    void gridValues(const GridBatch& batch, std::span<double> out) const override;
    Interval bound(const Box3& box) const override;

    const ExprProgram& program() const { return *mProgram; }

private:
    std::shared_ptr<const ExprProgram> mProgram;
    std::vector<FieldPtr> mInputs;
};

}  // namespace voxlat
