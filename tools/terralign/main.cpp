// terralign: map-based 6-DoF visual localisation. See `terralign --help`.
#include <cstdio>
#include <string>
#include <vector>

#include "commands.hpp"

namespace {

void print_help() {
  std::printf(
      "terralign: localise an aircraft camera against a geo-referenced map (orthoimages + DEM).\n\n"
      "usage: terralign <command> [options]     terralign <command> --help\n\ncommands:\n");
  for (const auto& c : terralign::cli::commands()) std::printf("  %-10s %s\n", c.name, c.summary);
  std::printf("\nPoses are \"x y z qw qx qy qz\": T_W_C, camera (x right, y down, z forward) to the\n"
              "map frame (x east, y north, z up, metres). Errors go to stderr with exit code 1\n"
              "(2 for a usage error).\n");
}

}  // namespace

int main(int argc, char** argv) {
  std::vector<std::string> args(argv + 1, argv + argc);
  if (args.empty() || args[0] == "--help" || args[0] == "-h" || args[0] == "help") {
    print_help();
    return args.empty() ? 2 : 0;
  }
  if (args[0] == "--version") {
    std::printf("terralign " TERRALIGN_VERSION "\n");
    return 0;
  }
  for (const auto& c : terralign::cli::commands()) {
    if (args[0] != c.name) continue;
    std::vector<std::string> rest(args.begin() + 1, args.end());
    for (const auto& a : rest)
      if (a == "--help" || a == "-h") {
        std::printf("%s", c.usage);
        return 0;
      }
    return c.run(rest);
  }
  std::fprintf(stderr, "terralign: unknown command '%s' (see terralign --help)\n", args[0].c_str());
  return 2;
}
