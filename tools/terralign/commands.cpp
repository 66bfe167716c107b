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
      {"align", "align one camera image to the map from a prior pose; prints the pose as JSON",
       "usage: terralign align --map MAP.json --camera CAMERA.json --image IMG --prior \"x y z qw qx qy qz\"\n"
       "                       --layer NAME [--method classic|nn] [--iterations N] [--robust none|huber|tukey]\n"
       "                       [--threads N] [--weights FILE] [--tilt-prior DEG] [--registration-floor PX]\n"
       "                       [--registration-floor-per-residual PX] [--refine N] [--min-sharpness S]\n"
       "                       [--max-disagreement PX] [--coarse-search PX]\n\n"
       "Renders LAYER at the prior, aligns the image to it (inverse-compositional LM on SE(3),\n"
       "4 levels, N iterations per level, default 20) and prints {\"pose\", \"covariance\",\n"
       "\"converged\", \"reason\", \"iterations\", \"ms\"}. The covariance is 6x6 over\n"
       "[dtheta (rad, world axes) ; dp (m, camera centre, world axes)]. A camera with distortion has\n"
       "its image undistorted to the same pinhole first. Exit code 3 when it did not converge (the\n"
       "pose printed is then the prior).\n"
       "--method nn: the learned tracker (encoder features, learned M-estimator, the same LM) at\n"
       "the weights' working size (half the camera's for the shipped weights); --weights FILE\n"
       "for weights other than the shipped weights/deep_iclk_s16.tlw.\n"
       "--tilt-prior DEG: the prior's roll and pitch are good to DEG degrees (1 sigma per axis; from\n"
       "an attitude reference such as an IMU, give its sigma); the answer's tilt is held to them\n"
       "with that weight while its heading and position stay free (default 3; 0: no tilt prior).\n"
       "Without it, across years of change, the learned tracker trades a tilt error for a shift.\n"
       "--registration-floor PX: the smallest registration error the covariance admits, in camera\n"
       "pixels (default 0.1, as same-year renders are registered), and --registration-floor-per-\n"
       "residual PX, at least PX per unit of the final residual (default 1; 0: the fixed floor\n"
       "alone): a map of another year than the image agrees with it less and is registered to it\n"
       "less well (same year the residual is 0.01-0.08, a year apart 0.8-1.5; docs/history.md).\n"
       "--refine N: up to N refinement passes (default 2; 0: none): while a converged answer turned\n"
       "by more than 0.05 degree from where its reference was rendered, the reference is rendered\n"
       "again at the answer and the image aligned again from it on the finest level. An alignment\n"
       "keeps part of its reference's tilt error as a shift; the pass takes it out (same year: a\n"
       "tenth of the error; docs/history.md). Only answers whose final residual is at most 1.0 (a\n"
       "correlation of 0.5: same-year maps) are refined. The answer and its covariance are the last\n"
       "pass's; a pass that fails leaves the one before. \"iterations\" and \"ms\" count every pass.\n"
       "--min-sharpness S, --max-disagreement PX and --coarse-search PX: as eval's (the converged\n"
       "tests and the search before the coarsest level).\n",
       run_align},
      {"eval", "the paper's evaluation: sampled poses, rendered pairs, error tables per method",
       "usage: terralign eval --map MAP.json --camera CAMERA.json --ref-layer A --query-layer B --count N\n"
       "                      --seed S --altitude LO:HI [--tilt DEG] [--methods init,classic:20,classic:50]\n"
       "                      [--robust none|huber|tukey] [--levels L] [--json OUT] [--overlays DIR]\n"
       "                      [--threads N] [--weights FILE] [--area MINX,MINY,MAXX,MAXY]\n"
       "                      [--min-sharpness S] [--max-disagreement PX] [--coarse-search PX]\n"
       "                      [--input-scale S] [--nn-levels L] [--imu-tilt DEG] [--tilt-prior DEG]\n"
       "                      [--prior-scale F] [--refine N]\n\n"
       "Samples N true poses with the whole footprint on the map (altitude above ground in\n"
       "[LO, HI] m, tilt off nadir up to DEG, any heading), perturbs each for the prior (rotation\n"
       "about a random axis by U[0, 6] deg, translation by U[0, 0.13 x altitude] m in a random\n"
       "direction), renders the reference from A at the prior and the query from B at the truth,\n"
       "runs each method from identity and prints a Markdown table of 3-D EPE (m), angle (deg),\n"
       "translation (m), 2-D EPE (px), success rates (2-D EPE < 1 px and < 5 px), the converged\n"
       "fraction, how many converged answers are within 5 px, and the alignment time (nn: with both\n"
       "encoders; neither includes rendering). Methods: init, classic:N, nn:N (the learned tracker,\n"
       "N iterations per level; --weights as for align). --area keeps every footprint inside a part\n"
       "of the map (e.g. ground the learned tracker was not trained on). Converged tests report an\n"
       "answer as failed (the prior): --max-disagreement PX, the agreement test of both trackers\n"
       "(default: 0.95 classic; the weight file's '# max-disagreement-px', 1.10 for the shipped\n"
       "weights; negative: none), when a second start 2 working px away in u and v settles more\n"
       "than PX away from it; --min-sharpness S, the learned tracker's sharpness test (default:\n"
       "the weight file's '# min-sharpness', none for the shipped weights; negative: none), when\n"
       "its feature agreement is within a factor S as good 2 px away. --coarse-search sets both\n"
       "trackers' search before the coarsest level (PX coarsest-level pixels each way; default: 4\n"
       "classic, 2 learned, which also turns up to 4 degrees about the optical axis; negative:\n"
       "none). --input-scale and --nn-levels run the learned tracker at another working size and\n"
       "number of levels than the weight file's (as the firmware does: 1 and 4 at 188 x 120).\n"
       "--imu-tilt DEG: the priors' tilt error is an attitude reference's, N(0, DEG^2) about each\n"
       "horizontal axis, instead of the protocol's (their heading error, the true poses and the\n"
       "priors' positions stay the protocol's); --tilt-prior DEG: both trackers hold the answer's\n"
       "tilt to the prior's with that sigma (as align's; default 3, 0: none, as the paper's\n"
       "protocol). --prior-scale F: every\n"
       "prior's rotation and move times F, the same draws otherwise (F < 1: priors nearer the\n"
       "truth, as a tracking loop's, to tell a narrow basin from a biased minimum). --json OUT\n"
       "also holds per pose and method the 2-D and 3-D EPE, the angle error and its tilt part\n"
       "(roll and pitch: between the true and the estimated view of the map's up), the converged\n"
       "flag and the tests' numbers, the true camera centre and the mean ground shift (estimate -\n"
       "truth, map axes, m).\n"
       "--refine N: both trackers' refinement passes, as align's (default 2; the time includes them).\n",
       run_eval},
      {"flight", "render a synthetic flight (frames, list, true poses) to test tracking",
       "usage: terralign flight --map MAP.json --camera CAMERA.json --layer NAME --path lawnmower|circle|FILE\n"
       "                        --speed M/S --rate HZ --out DIR [--altitude M] [--duration S] [--tilt DEG]\n"
       "                        [--noise SIGMA] [--blur R] [--exposure F] [--seed S] [--imu-tilt DEG]\n\n"
       "Flies the path (FILE: one 'x y' waypoint a line) at ALTITUDE m above the terrain (default\n"
       "800), heading along the path, and writes DIR/frames/NNNNNN.png, DIR/list.txt\n"
       "('timestamp path' a line) and DIR/truth.txt ('timestamp x y z qw qx qy qz'). Per frame:\n"
       "Gaussian noise of SIGMA grey levels, a box blur of radius R, an exposure gain in 1 +- F.\n"
       "--imu-tilt DEG also writes DIR/attitude.txt ('timestamp qw qx qy qz'): an attitude\n"
       "reference's readings, the true rotation with N(0, DEG^2) about each horizontal world axis\n"
       "(drawn per frame from a second stream; the frames stay the same), for track's --attitude.\n",
       run_flight},
      {"track", "track a flight: each frame's prior from the last estimate (constant velocity)",
       "usage: terralign track --map MAP.json --camera CAMERA.json --layer NAME --images LIST\n"
       "                       --init \"x y z qw qx qy qz\" [--method classic|nn] [--out poses.csv]\n"
       "                       [--truth POSES] [--json SUMMARY] [--iterations N] [--threads N]\n"
       "                       [--weights FILE] [--attitude FILE] [--tilt-prior DEG]\n"
       "                       [--init-velocity \"vx vy vz\"] [--registration-floor PX]\n"
       "                       [--registration-floor-per-residual PX]\n"
       "                       [--min-sharpness S] [--max-disagreement PX] [--coarse-search PX]\n"
       "                       [--nn-levels L] [--refine N]\n\n"
       "LIST has 'timestamp image-path' lines; --init is the pose at the first frame's time. Each\n"
       "frame's prior is the last converged estimate, moved by the velocity of the last two; a frame that fails (not converged, an unreadable or\n"
       "wrongly sized image, a timestamp going backwards) keeps the prediction, says why on stderr,\n"
       "and the track coasts on at that velocity. The CSV has per frame: timestamp, pose, converged, reason, iterations,\n"
       "ms, latitude, longitude, height (where the map has a CRS) and the 6x6 covariance (row-major,\n"
       "[dtheta (rad, world axes); dp (m)]). With --truth, the summary (stderr and --json) has\n"
       "frames, converged_fraction, position_rmse_m, angle_rmse_deg, the maxima and nees_mean.\n"
       "--init-velocity \"vx vy vz\": the velocity at --init (m/s along the map's axes, e.g. a GPS's\n"
       "last fix), so the first frames' priors move with the aircraft instead of waiting at --init\n"
       "until two frames have converged.\n"
       "--method nn tracks with the learned tracker (--weights as for align).\n"
       "--attitude FILE: an attitude reference (an IMU) that outlives the GPS, 'timestamp qw qx qy\n"
       "qz' a line, one per frame at its timestamp; a prior not yet predicted from two converged\n"
       "frames takes its roll and pitch (the heading stays the prior's). --tilt-prior DEG holds\n"
       "each answer's tilt to it with that sigma, without --attitude to the prediction's (as\n"
       "align's; default 3, 0: none).\n"
       "--registration-floor PX and --registration-floor-per-residual PX: as align's (defaults 0.1\n"
       "and 1 camera pixels).\n"
       "--min-sharpness S, --max-disagreement PX and --coarse-search PX: as eval's (the converged\n"
       "tests, negative: none; the search before the coarsest level, -1: none).\n"
       "--nn-levels L: the learned tracker aligns on the finest L of the weight file's levels (as\n"
       "eval's; 0: all).\n"
       "--refine N: as align's (default 2): a frame whose answer turned by more than 0.05 degree\n"
       "from its prediction is aligned again from a reference rendered at it, as the first frames\n"
       "of a track started from an IMU's tilt are; the frames after them are not.\n",
       run_track},
      {"dataset", "render training pairs for the learned tracker (every ordered pair of years)",
       "usage: terralign dataset --map MAP.json --camera CAMERA.json --count N --seed S --out DIR\n"
       "                         [--altitude LO:HI] [--tilt DEG] [--split-fraction F] [--scale S]\n"
       "                         [--layers all|NAME,...] [--no-augment]\n\n"
       "Samples poses as eval does (default 700:900 m, tilt 10 deg), a fraction F (default 0.2) in\n"
       "a strip at the east (or north) end of the map for validation and the rest beside it, so\n"
       "that no ground is in both. Per pose DIR/<split>/<id>/ holds ref_<layer>.png for every layer at the prior,\n"
       "ref_depth.pfm, and query_<layer>.png at the true pose (augmented: exposure, white balance,\n"
       "blur, noise; --no-augment turns it off). DIR/index.csv lists every ordered pair of layers\n"
       "per pose with intrinsics and T_query_ref. --scale resizes the camera (0.25: 188x120).\n"
       "The same seed gives the same bytes.\n",
       run_dataset},
  };
  return list;
}

}  // namespace terralign::cli
