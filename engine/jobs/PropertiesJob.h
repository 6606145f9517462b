/// @file PropertiesJob.h
/// @brief What a lattice does: effective stiffness and conductivity of one periodic cell of a
/// recipe's result (engine/properties), in MPa, with the engineering constants users quote and a
/// picture of the directional Young's modulus.
#pragma once

#include "engine/core/JobContext.h"
#include "engine/properties/Homogenization.h"
#include "engine/recipe/Recipe.h"
#include "fields/FieldNode.h"

#include <nlohmann/json.hpp>

#include <string>

namespace voxlat {

/// The homogenized cell, as report.json's `properties` and `voxlat properties --json`.
struct PropertiesResult {
    nlohmann::json report;
    Matrix6 stiffnessMPa{};
    double relativeDensity = 0.0;
};

/// Homogenizes one periodic cell of @a field (the recipe's result, levels solved): the cell is
/// `properties: {cell, origin, resolution}`, or one period of the field along each axis starting
/// at @a domainMin, or (a finite frame of identical cells, FieldNode::repeatZone()) the first
/// whole cell of the frame's repeating interior; voxels of about @a voxel. Needs `material:`. Throws InputError for a
/// missing material or period (naming the recipe line), JobError for a cell with no solid or one that carries no load
/// along any axis.
PropertiesResult computeProperties(const FieldNode& field, const Recipe& recipe, const Vec3d& domainMin, double voxel,
                                   const JobContext* context);

/// A shaded picture (PNG, @a size pixels square) of the directional Young's modulus surface
/// E(d) of @a C: the surface r = E(d) / max E over the unit sphere.
std::string directionalModulusPng(const Matrix6& C, int size = 640);

/// The result as a small text table for a terminal (the library never prints; the CLI does).
std::string propertiesTable(const nlohmann::json& properties);

}  // namespace voxlat
