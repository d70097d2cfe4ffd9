#pragma once
/// @file report_json.h
/// JSON forms of solver reports, shared by the CLI report and the benchmark results so that
/// both always carry the same fields.

#include <nlohmann/json.hpp>

#include "core/methods/deform_types.h"

namespace meshdeform::io {

/// One outer iteration: energy, energy_before (the entering iterate after step one), E_theta, E_phi,
/// elapsed time, PCG iterations, normal sweeps,
/// whether step two refactored, and the per-phase seconds.
nlohmann::json iteration_to_json(const core::IterationInfo& info);

/// The per-iteration history of a solve, as an array of iteration_to_json objects.
nlohmann::json history_to_json(const std::vector<core::IterationInfo>& history);

}  // namespace meshdeform::io
