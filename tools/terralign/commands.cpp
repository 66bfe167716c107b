#include "commands.hpp"

namespace terralign::cli {

const std::vector<Command>& commands() {
  static const std::vector<Command> list = {
      {"info", "print a map's layers, sizes, resolution, extents, CRS and DEM range",
       "usage: terralign info --map MAP.json [--json]\n\n"
       "Loads the map manifest and every raster it names, checks them, and prints the CRS, the\n"
       "DEM (or constant height) and its range, each layer's size, resolution, extent and\n"
       "valid fraction, and the area covered by every layer. --json prints the same as JSON.\n",
       run_info},
  };
  return list;
}

}  // namespace terralign::cli
