// The terralign sub-commands. Each returns the process exit code; errors go to stderr.
#pragma once

#include <string>
#include <vector>

namespace terralign::cli {

struct Command {
  const char* name;
  const char* summary;
  const char* usage;  // full --help text
  int (*run)(const std::vector<std::string>& args);
};

const std::vector<Command>& commands();

int run_info(const std::vector<std::string>& args);
int run_render(const std::vector<std::string>& args);
int run_align(const std::vector<std::string>& args);
int run_eval(const std::vector<std::string>& args);
int run_flight(const std::vector<std::string>& args);
int run_track(const std::vector<std::string>& args);
int run_dataset(const std::vector<std::string>& args);

}  // namespace terralign::cli
