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
      {"render", "render the camera's view of every (or some) layer, with metric depth",
       "usage: terralign render --map MAP.json --camera CAMERA.json (--pose \"x y z qw qx qy qz\" | --poses FILE)\n"
       "                        --out DIR [--layers all|NAME,...] [--threads N] [--lod-error PX]\n\n"
       "Writes DIR/<layer>.png (RGB), DIR/<layer>_valid.png (255 where the layer has data),\n"
       "DIR/depth.pfm (float32 metres along the optical axis, NaN where no terrain) and\n"
       "DIR/depth.png (a preview). With --poses (one pose a line), each view goes to DIR/<index>/\n"
       "with a progress bar on stderr; a view that fails is reported and not written.\n",
       run_render},
  };
  return list;
}

}  // namespace terralign::cli
