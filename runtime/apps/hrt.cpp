// `hrt`: the runtime's command. main() only parses argv (CLI11) and maps
// failures to one line on stderr plus a distinct exit code; the work is in
// the library (hrtcore) and the cmd_*.cpp files.
#include <cstdio>
#include <cstring>
#include <exception>
#include <string>

#include "commands.h"
#include "hrt/files.h"
#include "hrt/model.h"

namespace {

// "check, query, bench, run, gl-info": the registered subcommands, in order.
std::string command_list(CLI::App& app) {
  std::string out;
  for (const CLI::App* sub : app.get_subcommands([](const CLI::App*) { return true; }))
    out += (out.empty() ? "" : ", ") + sub->get_name();
  return out;
}

// One line for a CLI11 parse error. CLI11 prints "A subcommand is required"
// for an unknown command and adds a second "Run with --help" line; scripts
// and users get the unknown word and the valid commands instead.
std::string usage_line(CLI::App& app, int argc, char** argv, const CLI::ParseError& e) {
  std::string what = e.what();
  for (char& c : what)
    if (c == '\n' || c == '\r') c = ' ';
  const std::vector<CLI::App*> used = app.get_subcommands();
  if (used.empty()) {
    for (int i = 1; i < argc; ++i) {
      if (argv[i][0] == '-') continue;
      return "unknown command '" + std::string(argv[i]) + "' (commands: " + command_list(app) + "); see hrt --help";
    }
    return "a command is required (" + command_list(app) + "); see hrt --help";
  }
  return what + "; see hrt " + used.back()->get_name() + " --help";
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"hrt: haptic texture rendering runtime (6-DoF forces and torques between textured models)"};
  app.require_subcommand(1);
  app.set_version_flag("--version", "hrt 0.1.0");
  hrt_cli::register_check(app);
  hrt_cli::register_query(app);
  hrt_cli::register_bench(app);
  hrt_cli::register_run(app);
  hrt_cli::register_gl_info(app);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    // --help and --version: CLI11 prints them and they succeed.
    if (e.get_exit_code() == static_cast<int>(CLI::ExitCodes::Success)) return app.exit(e);
    std::fprintf(stderr, "hrt: %s\n", usage_line(app, argc, argv, e).c_str());
    return hrt_cli::kUsage;
  } catch (const hrt_cli::Exit& e) {
    if (e.what()[0]) std::fprintf(stderr, "hrt: %s\n", e.what());
    return e.code;
  } catch (const hrt::BundleError& e) {
    // "hrt: error: <class>: <bundle>/<file>: <problem>" from every command
    // (the class as `hbake validate` names it), one printable line.
    std::fprintf(stderr, "hrt: error: %s: %s\n", hrt::to_string(e.error_class()),
                 hrt::printable(e.what(), 600).c_str());
    return hrt_cli::kBundle;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "hrt: internal error: %s\n", e.what());
    return hrt_cli::kInternal;
  }
  return 0;
}
