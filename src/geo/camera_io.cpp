// Camera files (JSON) in and out.
#include <terralign/geo/camera.hpp>

#include <nlohmann/json.hpp>

#include <terralign/geo/file.hpp>
#include <terralign/geo/number_text.hpp>

#include "json_util.hpp"

namespace terralign::geo {

Result<CameraModel> parse_camera(const std::string& text, const std::string& name) {
  TERRALIGN_TRY_ASSIGN(const nlohmann::json j, parse_json_text(text, name));
  TERRALIGN_TRY(check_keys(j, {"width", "height", "fx", "fy", "cx", "cy", "distortion", "name"}, name));
  CameraModel c;
  TERRALIGN_TRY_ASSIGN(c.width, json_int(j, "width", name));
  TERRALIGN_TRY_ASSIGN(c.height, json_int(j, "height", name));
  TERRALIGN_TRY_ASSIGN(c.fx, json_number(j, "fx", name));
  TERRALIGN_TRY_ASSIGN(c.fy, json_number(j, "fy", name));
  TERRALIGN_TRY_ASSIGN(c.cx, json_number(j, "cx", name));
  TERRALIGN_TRY_ASSIGN(c.cy, json_number(j, "cy", name));
  if (j.contains("distortion")) {
    const auto& d = j["distortion"];
    const std::string where = name + ": distortion";
    TERRALIGN_TRY(check_object(d, where));
    TERRALIGN_TRY_ASSIGN(const std::string model, json_string(d, "model", where));
    auto opt = [&](const char* key, double& out) -> Status {
      if (!d.contains(key)) return Ok{};
      TERRALIGN_TRY_ASSIGN(out, json_number(d, key, where));
      return Ok{};
    };
    if (model == "none") {
      TERRALIGN_TRY(check_keys(d, {"model"}, where));
    } else if (model == "radtan") {
      c.model = DistortionModel::RadTan;
      TERRALIGN_TRY(check_keys(d, {"model", "k1", "k2", "p1", "p2", "k3"}, where));
      TERRALIGN_TRY(opt("k1", c.k[0]));
      TERRALIGN_TRY(opt("k2", c.k[1]));
      TERRALIGN_TRY(opt("p1", c.k[2]));
      TERRALIGN_TRY(opt("p2", c.k[3]));
      TERRALIGN_TRY(opt("k3", c.k[4]));
    } else if (model == "equidistant") {
      c.model = DistortionModel::Equidistant;
      TERRALIGN_TRY(check_keys(d, {"model", "k1", "k2", "k3", "k4"}, where));
      TERRALIGN_TRY(opt("k1", c.k[0]));
      TERRALIGN_TRY(opt("k2", c.k[1]));
      TERRALIGN_TRY(opt("k3", c.k[2]));
      TERRALIGN_TRY(opt("k4", c.k[3]));
    } else {
      return Error{where + ": unknown model '" + model + "' (none, radtan, equidistant)"};
    }
  }
  TERRALIGN_TRY(c.validate(name));
  return c;
}

Result<CameraModel> load_camera(const std::string& path) {
  TERRALIGN_TRY_ASSIGN(const auto bytes, read_file(path, std::size_t{1} << 20));
  return parse_camera(std::string(bytes.begin(), bytes.end()), path);
}

std::string camera_to_json(const CameraModel& c) {
  nlohmann::json j = {{"width", c.width}, {"height", c.height}, {"fx", c.fx},
                      {"fy", c.fy},       {"cx", c.cx},         {"cy", c.cy}};
  nlohmann::json d = {{"model", to_string(c.model)}};
  if (c.model == DistortionModel::RadTan) {
    d["k1"] = c.k[0]; d["k2"] = c.k[1]; d["p1"] = c.k[2]; d["p2"] = c.k[3]; d["k3"] = c.k[4];
  } else if (c.model == DistortionModel::Equidistant) {
    d["k1"] = c.k[0]; d["k2"] = c.k[1]; d["k3"] = c.k[2]; d["k4"] = c.k[3];
  }
  j["distortion"] = d;
  return j.dump(2);
}

}  // namespace terralign::geo
