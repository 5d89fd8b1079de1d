// `hrt`: the runtime's command. main() only parses argv (CLI11) and maps
// failures to one line on stderr plus a distinct exit code; the work is in
// the library (hrtcore) and the cmd_*.cpp files.
#include <cstdio>
#include <exception>

#include "commands.h"
#include "hrt/model.h"

int main(int argc, char** argv) {
  CLI::App app{"hrt: haptic texture rendering runtime (6-DoF forces and torques between textured models)"};
  app.require_subcommand(1);
  app.set_version_flag("--version", "hrt 0.1.0");
  hrt_cli::register_check(app);
  hrt_cli::register_query(app);
  hrt_cli::register_bench(app);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e) == 0 ? 0 : hrt_cli::kUsage;
  } catch (const hrt_cli::Exit& e) {
    if (e.what()[0]) std::fprintf(stderr, "hrt: %s\n", e.what());
    return e.code;
  } catch (const hrt::BundleError& e) {
    std::fprintf(stderr, "hrt: error: %s\n", e.what());
    return hrt_cli::kBundle;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "hrt: internal error: %s\n", e.what());
    return hrt_cli::kInternal;
  }
  return 0;
}
