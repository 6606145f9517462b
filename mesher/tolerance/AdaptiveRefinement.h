/// @file AdaptiveRefinement.h
/// @brief Refinement of a coarse projected mesh until every triangle stays within a tolerance of
/// the surface: longest edges bisected at points on the surface, where the error is.
///
/// A projected mesh's error is its chord error, which grows as the square of its triangles' size
/// and with the surface's curvature. Meshing at the recipe's voxel and decimating makes millions
/// of triangles only to join most of them again; meshing on a coarse grid and bisecting only the
/// triangles that stray makes the triangles where the curvature asks for them, in a few passes
/// over the mesh (W9: 0.4 mm voxels refined to 0.009 mm in 3 rounds).
#pragma once

#include "fields/core/FieldNode.h"
#include "mesher/extract/MarchingCubes.h"
#include "mesher/extract/TriangleMesh.h"

#include <cstddef>
#include <optional>

namespace voxlat {

struct AdaptiveRefinementOptions {
    /// Every triangle left passes triangleWithin() at this (mm).
    double tolerance = 0.01;
    /// The level set (the solid is f < level).
    double level = 0.0;
    /// The domain box the mesh was cut by: the solid is also inside it. Points on a face stay on
    /// it (an edge along a crease is split on the crease).
    std::optional<Box3> box;
    /// A new vertex lies within this of the midpoint of the edge it splits (mm).
    double maxMove = 0.05;
    /// Newton stops once the point is within this of the surface (mm).
    double newtonTolerance = 1e-6;
    /// Newton steps per new vertex at most.
    int maxIterations = 12;
    /// Rounds of bisection at most.
    int rounds = 16;
};

/// What refineToTolerance() did.
struct AdaptiveRefinementStats {
    std::size_t trianglesBefore = 0, trianglesAfter = 0;
    /// Edges split, over all rounds.
    std::size_t splits = 0;
    /// Edge splits dropped: Newton found no point on the surface within maxMove of the midpoint,
    /// or a piece would have turned over or lost its area.
    std::size_t dropped = 0;
    /// Edges flipped: a triangle whose split was dropped (a needle) and the one across its
    /// longest edge, where the flip makes the pair rounder.
    std::size_t flips = 0;
    /// Corners on a face of the box left off the surface (crease points the box cut could not
    /// move without turning a piece over), moved onto it once their triangles allowed.
    std::size_t cornersMoved = 0;
    /// Triangles still outside the tolerance at the end (none tried all three edges in vain).
    std::size_t remaining = 0;
    int rounds = 0;
    /// Whether it gave up: a round dropped more than a twentieth of its splits (the field has
    /// creases of its own, which bisection does not resolve); remaining counts that round's.
    bool abandoned = false;
    /// The largest deviation of the mesh it was given, by the same check (the coarse mesh's chord
    /// error, with its creases and caps).
    double maxBefore = 0.0;
    /// The deviation of the mesh it leaves, from its own check of every triangle (the
    /// TriangleQuadratic through the distances at the corners, edge midpoints and centre): the
    /// largest |q| (exact) plus the centre's margin, and the root of q squared
    /// integrated over the surface over its area. Measured on the triangles as stored (float).
    double maxDeviation = 0.0, rmsDeviation = 0.0;
    /// Field points behind them: the vertices and four per triangle.
    std::size_t deviationSamples = 0;
};

/// Bisects the triangles of @a mesh (closed, vertices on the level set of @a field, e.g. after
/// projectToSurface() and clipToBox()) that fail triangleWithin() at options.tolerance, in
/// rounds: each such triangle's edge bending most off its chord (once that split was dropped, the
/// next) is split in both triangles that share it, so the mesh stays closed, manifold and
/// oriented; a triangle whose split was dropped has its longest edge flipped first where that
/// makes the pair rounder (flipLongestEdges in the source: never an edge on a box face). The new
/// vertex goes from the edge's midpoint onto the level set by Newton steps along the gradient;
/// on an edge whose ends lie on one face of options.box the steps stay in that face (on two
/// faces, the midpoint stays), and a point that would leave the box is held on the face it
/// crosses (a point on the crease). A split is dropped when Newton fails within options.maxMove
/// or a piece would turn against its parent or lose its area (as stored in float). The signed
/// distance is (f - level) / |grad f| (on a face of the box its positive part). Triangles
/// are not checked against each other: the caller checks for crossings. New vertices are
/// appended in the order of their edges, evaluation runs in fixed batches and the decisions that
/// depend on each other run in triangle order, so the bytes are the same for any thread count.
/// The stats carry the deviation of the mesh it leaves, from its own check of every triangle. @a progress (optional)
/// runs from 0 to 1 and may throw to cancel.
AdaptiveRefinementStats refineToTolerance(TriangleMesh& mesh, const FieldNode& field,
                                          const AdaptiveRefinementOptions& options, const ProgressFn& progress = {});

}  // namespace voxlat
