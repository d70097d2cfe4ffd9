#pragma once
/// @file commands.h
/// The subcommands of meshdeform-cli. Each takes the words after its name and returns the process
/// exit code: 0 success, 1 runtime error (the Status is printed), 2 usage error.

#include <string>
#include <vector>

namespace meshdeform::cli {

/// Exit codes.
inline constexpr int kExitOk = 0;
inline constexpr int kExitRuntimeError = 1;
inline constexpr int kExitUsage = 2;

/// `meshdeform-cli deform`: deforms a mesh file with a .sel/.def pair or a JSON edit spec.
int run_deform(const std::vector<std::string>& args);
/// `meshdeform-cli generate`: writes the procedural Table 1 models as .off/.sel/.def.
int run_generate(const std::vector<std::string>& args);
/// `meshdeform-cli demo`: deforms the built-in cylinder and writes a GLB, an OBJ and a report.
int run_demo(const std::vector<std::string>& args);
/// Dispatches on the first word (`args` excludes the program name).
int run_cli(const std::vector<std::string>& args);

}  // namespace meshdeform::cli
