#pragma once
/// @file load_runner.h
/// Runs a load test against a meshdeform-server through the generated gRPC stubs (deliberately
/// not the client library: it measures the protocol). One thread per session and per watcher,
/// synchronous API, every call with a deadline, every thread joined before run_load_test returns.
///
/// Phases: (1) GetServerStats; (2) every session creates its mesh, sets its handles, opens its
/// watchers and waits for their join snapshots; (3) when all are set up, the scripted drags run
/// until each session sent --moves moves or --duration (counted from the start) ends; a move in
/// flight then has at most a 5 s drain; (4) GetServerStats with the sessions still open;
/// (5) sessions close, watchers end (cancelled after 5 s if the close did not end them);
/// (6) GetServerStats again.

#include <string>

#include "client_cpp/loadtest/options.h"
#include "client_cpp/loadtest/run_result.h"

namespace meshdeform::loadtest {

/// A mesh file to upload, read and typed before the run.
struct MeshUpload {
  std::string bytes;
  int format = 0;    ///< meshdeform.v1.MeshFormat value
  std::string name;  ///< the file's name, for the report
};

/// Reads `path` and picks the format from its extension (.obj .off .ply .stl .glb .gltf).
/// @return false with `error` set for an unreadable file or an unknown extension.
bool load_mesh_upload(const std::string& path, MeshUpload& upload, std::string& error);

/// Runs the load test. Never throws; failures are recorded in the result.
/// @param[in] options  validated options (parse_options returned Run).
/// @param[in] upload   the mesh to upload when options.mesh_path is set; ignored otherwise.
RunResult run_load_test(const Options& options, const MeshUpload& upload);

}  // namespace meshdeform::loadtest
