// Subcommands of `hrt`. Each register_* adds one subcommand to the app and
// sets its callback; the callback returns through hrt::Exit (exit code) so
// main can map user errors to clean one-line messages.
#pragma once

#include <CLI/CLI.hpp>
#include <stdexcept>
#include <string>

namespace hrt_cli {

// Exit codes of `hrt` (documented in docs/guides/runtime.md, "hrt check").
enum ExitCode : int {
  kOk = 0,
  kUsage = 2,          // bad option or argument
  kBundle = 3,         // a bundle failed to load (io, version, schema, hash, mesh, atlas, pieces)
  kScene = 4,          // hrt run: bad scene file or trajectory (file, key, what)
  kDevice = 5,         // hrt run: the device could not be opened (bind, plugin, ...)
  kOutput = 6,         // hrt run: the trace or device log could not be written
  kGl = 7,             // no usable OpenGL 4.5 core context (EGL): the message names what is missing
  kInternal = 70,      // a bug: please report
  kInterrupted = 130,  // hrt run: Ctrl-C / SIGTERM (device ramped to zero, trace written)
};

// Thrown by a subcommand to end with a specific exit code and one message line.
struct Exit : std::runtime_error {
  int code;
  Exit(int c, const std::string& msg) : std::runtime_error(msg), code(c) {}
};

void register_check(CLI::App& app);    // hrt check BUNDLE: load, verify, summarize
void register_query(CLI::App& app);    // hrt query A B --pose-a ... --pose-b ...
void register_bench(CLI::App& app);    // hrt bench
void register_run(CLI::App& app);      // hrt run SCENE.toml
void register_gl_info(CLI::App& app);  // hrt gl-info

}  // namespace hrt_cli
