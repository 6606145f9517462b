// Recipe node types for primitives, booleans and transforms.
#include "engine/recipe/FieldBuilder.h"
#include "fields/shapes/Boolean.h"
#include "fields/shapes/BoxField.h"
#include "fields/shapes/Cylinder.h"
#include "fields/shapes/Sphere.h"
#include "fields/shapes/Transform.h"

namespace voxlat {

namespace {

FieldPtr buildSphere(FieldBuilder&, const RecipeNode& spec, const std::string&)
{
    const RecipeNode s = spec["sphere"];
    s.checkKeys({"center", "radius"});
    return std::make_shared<Sphere>(s.has("center") ? s["center"].vec3() : Vec3d(0.0), s["radius"].positiveNumber());
}

FieldPtr buildBox(FieldBuilder&, const RecipeNode& spec, const std::string&)
{
    return std::make_shared<BoxField>(spec["box"].box());
}

FieldPtr buildCylinder(FieldBuilder&, const RecipeNode& spec, const std::string&)
{
    const RecipeNode c = spec["cylinder"];
    c.checkKeys({"center", "axis", "radius", "height"});
    const Vec3d axis = c.has("axis") ? c["axis"].vec3() : Vec3d(0, 0, 1);
    if (axis.length() <= 0.0) c["axis"].fail("the axis must not be the zero vector");
    return std::make_shared<Cylinder>(c.has("center") ? c["center"].vec3() : Vec3d(0.0), axis,
                                      c["radius"].positiveNumber(), c["height"].positiveNumber());
}

NodeType booleanType(const std::string& key, BooleanOp op)
{
    using namespace valueSchema;
    const std::string meaning = op == BooleanOp::Union          ? "fields joined (min)"
                                : op == BooleanOp::Intersection ? "fields intersected (max)"
                                                                : "the first field minus all the others";
    return {key,
            {{key, fieldList(), meaning, "required"}, {"blend", number(), "smooth blend radius (mm), 0 = sharp", "0"}},
            [key, op](FieldBuilder& b, const RecipeNode& spec, const std::string& name) -> FieldPtr {
                const RecipeNode list = spec[key];
                const std::size_t minimum = op == BooleanOp::Difference ? 2 : 1;
                if (!list.isSequence() || list.size() < minimum)
                    list.fail("expected a list of fields (names or inline nodes), like [a, b]");
                std::vector<FieldPtr> operands;
                for (std::size_t i = 0; i < list.size(); ++i)
                    operands.push_back(b.operand(list.at(i), name + "/" + std::to_string(i + 1)));
                double blend = 0.0;
                if (spec.has("blend")) {
                    blend = spec["blend"].number();
                    if (blend < 0.0) spec["blend"].fail("the blend radius must be zero or positive (millimetres)");
                }
                return std::make_shared<BooleanField>(op, std::move(operands), blend);
            }};
}

FieldPtr transformed(FieldBuilder& b, const RecipeNode& spec, const std::string& name, const Mat3d& linear,
                     const Vec3d& translation)
{
    return std::make_shared<TransformField>(b.operand(spec["field"], name + "/field"), linear, translation);
}

FieldPtr buildTranslate(FieldBuilder& b, const RecipeNode& spec, const std::string& name)
{
    return transformed(b, spec, name, Mat3d::identity(), spec["translate"].vec3());
}

FieldPtr buildRotate(FieldBuilder& b, const RecipeNode& spec, const std::string& name)
{
    const RecipeNode r = spec["rotate"];
    r.checkKeys({"axis", "degrees"});
    const Vec3d axis = r["axis"].vec3();
    if (axis.length() <= 0.0) r["axis"].fail("the rotation axis must not be the zero vector");
    return transformed(b, spec, name, TransformField::rotation(axis, r["degrees"].number()), Vec3d(0.0));
}

FieldPtr buildScale(FieldBuilder& b, const RecipeNode& spec, const std::string& name)
{
    const RecipeNode s = spec["scale"];
    const Vec3d factors = s.scalarOrVec3();
    for (int a = 0; a < 3; ++a)
        if (!(factors[a] >= 1e-9 && factors[a] <= 1e9))
            s.fail(
                "scale factors are from 1e-9 to 1e9 (a factor outside turns lengths into numbers a double cannot "
                "keep)");
    Mat3d m = Mat3d::zero();
    for (int a = 0; a < 3; ++a) m(a, a) = factors[a];
    return transformed(b, spec, name, m, Vec3d(0.0));
}

}  // namespace

void addShapeNodeTypes(std::vector<NodeType>& types)
{
    using namespace valueSchema;
    types.push_back(
        {"sphere",
         {{"sphere",
           object({{"center", vec3(), "centre (mm)", "[0, 0, 0]"}, {"radius", number(), "radius (mm)", "required"}},
                  {"radius"}),
           "a ball: {center, radius} (exact signed distance)", "required"}},
         buildSphere});
    types.push_back({"box", {{"box", box(), "[[x0, y0, z0], [x1, y1, z1]] (mm)", "required"}}, buildBox});
    types.push_back({"cylinder",
                     {{"cylinder",
                       object({{"center", vec3(), "centre (mm)", "[0, 0, 0]"},
                               {"axis", vec3(), "axis direction", "[0, 0, 1]"},
                               {"radius", number(), "radius (mm)", "required"},
                               {"height", number(), "length along the axis (mm)", "required"}},
                              {"radius", "height"}),
                       "a capped cylinder: {center, axis, radius, height}", "required"}},
                     buildCylinder});
    types.push_back(booleanType("union", BooleanOp::Union));
    types.push_back(booleanType("intersection", BooleanOp::Intersection));
    types.push_back(booleanType("difference", BooleanOp::Difference));
    const KeySpec transformed{"field", field(), "the field transformed", "required"};
    types.push_back({"translate", {{"translate", vec3(), "offset (mm)", "required"}, transformed}, buildTranslate});
    types.push_back(
        {"rotate",
         {{"rotate",
           object({{"axis", vec3(), "rotation axis", "required"}, {"degrees", number(), "angle (degrees)", "required"}},
                  {"axis", "degrees"}),
           "{axis, degrees}: a rotation about the origin", "required"},
          transformed},
         buildRotate});
    types.push_back(
        {"scale", {{"scale", numberOrVec3(), "factor, or [x, y, z]", "required"}, transformed}, buildScale});
}

}  // namespace voxlat
