/// @file TrialRecipe.h
/// @brief Trial jobs (PropertyDesign's density and sigma searches, PiecesAdvice's sigma, a frame's
/// repeated cell, a graded lattice's slabs): their recipes are made by trialRecipe
/// (engine/recipe/Recipe.h) from a typed FieldEdit; here, how a trial hears its parent's cancel,
/// and how a search's trials skip the fine density solve of their result (CellLevelTrial).
#pragma once

#include "engine/core/JobContext.h"
#include "engine/recipe/Recipe.h"

#include <string>

namespace voxlat {

/// Makes a trial job's own context (its warnings kept apart) stop when @a parent is cancelled:
/// its stages' progress checks look at the parent too, ten times a second. Without it a
/// SIGTERM during `optimize:` went unheard until every trial had run.
inline void followCancel(JobContext& trial, const JobContext* parent)
{
    if (!parent) return;
    trial.setProgressCallback([&trial, parent](const std::string&, std::uint64_t, std::uint64_t) {
        if (parent->cancelled()) trial.cancel();
    });
    if (parent->cancelled()) trial.cancel();
}

/// While one lives, the jobs this thread runs are trials that only homogenize their result
/// (PropertyDesign's density and sigma searches): the result's `density:` level is solved on the
/// homogenized cell's own voxel model anyway (computeProperties), so the solve over the density
/// box only has to place the level near it, and takes a voxel three times coarser (Job.cpp's
/// kCoarseLevelFactor). The cell is the same voxel model as a full job's: its solid voxels are
/// the lowest values of field minus level whatever the level, and near the solved level that
/// subtraction is exact, so the moduli come out bit for bit the same; the `level` a trial reports
/// differs in its last digits. A frame's repeated cell (a job inside the trial) is a trial too.
class CellLevelTrial {
public:
    CellLevelTrial() { ++depth(); }
    ~CellLevelTrial() { --depth(); }
    CellLevelTrial(const CellLevelTrial&) = delete;
    CellLevelTrial& operator=(const CellLevelTrial&) = delete;
    /// Whether one lives on this thread.
    static bool active() { return depth() > 0; }

private:
    static int& depth()
    {
        thread_local int trials = 0;
        return trials;
    }
};

}  // namespace voxlat
