// meshdeform-loadtest entry point: flags, the run, the reports and the exit code.
#include <cstdio>
#include <exception>
#include <fstream>
#include <iostream>
#include <string>
#include <vector>

#include "client_cpp/loadtest/load_runner.h"
#include "client_cpp/loadtest/options.h"
#include "client_cpp/loadtest/report.h"

namespace {

using namespace meshdeform::loadtest;

bool write_file(const std::string& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out << text;
  out.close();
  if (!out) {
    std::cerr << "meshdeform-loadtest: cannot write " << path << "\n";
    return false;
  }
  return true;
}

int run(const std::vector<std::string>& args) {
  Options options;
  const ParseOutcome outcome = parse_options(args, options);
  if (outcome.kind == ParseOutcome::Kind::Help) {
    std::cout << usage_text();
    return kExitOk;
  }
  if (outcome.kind == ParseOutcome::Kind::UsageError) {
    std::cerr << "meshdeform-loadtest: " << outcome.message << "\n" << usage_text();
    return kExitUsage;
  }
  MeshUpload upload;
  if (!options.mesh_path.empty()) {
    std::string error;
    if (!load_mesh_upload(options.mesh_path, upload, error)) {
      std::cerr << "meshdeform-loadtest: " << error << "\n";
      return kExitUsage;
    }
  }

  const RunResult result = run_load_test(options, upload);
  const Aggregate totals = aggregate(result);
  std::cout << summary_text(result, totals) << std::flush;
  bool is_written = true;
  if (!options.json_path.empty()) {
    is_written = write_file(options.json_path, report_json(result, totals)) && is_written;
  }
  if (!options.markdown_path.empty()) {
    is_written = write_file(options.markdown_path, report_markdown(result, totals)) && is_written;
  }
  if (totals.sessions_set_up == 0) {
    std::cerr << "meshdeform-loadtest: setup failed for every session\n";
    return kExitRunFailed;
  }
  if (!is_written) return kExitRunFailed;
  if (options.fail_on_errors && totals.moves_failed > 0) {
    std::cerr << "meshdeform-loadtest: " << totals.moves_failed
              << " moves failed (--fail-on-errors)\n";
    return kExitRunFailed;
  }
  return kExitOk;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    return run(std::vector<std::string>(argv + 1, argv + argc));
  } catch (const std::exception& e) {
    std::fprintf(stderr, "meshdeform-loadtest: error: %s\n", e.what());
  } catch (...) {
    std::fprintf(stderr, "meshdeform-loadtest: error: unknown exception\n");
  }
  return kExitRunFailed;
}
