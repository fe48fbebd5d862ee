#pragma once
/// @file run_errors.hpp
/// Errors of a localization run report's samples against a reference, filled in after
/// the run (studies, simulated drives): the same evaluation as `polmap eval`
/// (trajectory_eval.hpp), so a report's errors and the eval's figures agree.
#include <vector>

#include "polmap/eval/trajectory_eval.hpp"
#include "polmap/schema/localization_run.hpp"

namespace polmap::eval {

/// Sets `error` on every sample of `run` that evaluate_trajectory evaluates against
/// `reference` (same filters: speed, carrier phase, status) and clears it on the others;
/// sets run.reference = `kind`. Returns the metrics of the evaluated samples.
TrajectoryMetrics attach_run_errors(LocalizationRun& run,
                                    const std::vector<ReferenceSample>& reference,
                                    RunReference kind, const TrajectoryEvalOptions& options = {});

}  // namespace polmap::eval
