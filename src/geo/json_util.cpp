#include "json_util.hpp"

#include <cmath>

#include <terralign/geo/file.hpp>
#include <terralign/geo/number_text.hpp>

namespace terralign::geo {

Result<nlohmann::json> parse_json_text(const std::string& text, const std::string& name) {
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(text);
  } catch (const nlohmann::json::parse_error& e) {
    // e.byte is the 1-based offset of the byte where parsing stopped.
    const std::size_t upto = std::min<std::size_t>(e.byte > 0 ? e.byte - 1 : 0, text.size());
    std::size_t line = 1, col = 1;
    for (std::size_t i = 0; i < upto; ++i) {
      if (text[i] == '\n') { ++line; col = 1; } else { ++col; }
    }
    std::string what = e.what();
    const auto colon = what.find("syntax error");
    if (colon != std::string::npos) what = what.substr(colon);
    return Error{name + ":" + std::to_string(line) + ":" + std::to_string(col) + ": JSON " + what};
  } catch (const nlohmann::json::exception& e) {  // e.g. a number too large for a double
    return Error{name + ": JSON " + e.what()};
  }
  return j;
}

Result<nlohmann::json> parse_json_file(const std::string& path) {
  TERRALIGN_TRY_ASSIGN(auto bytes, read_file(path, std::size_t{64} << 20));
  return parse_json_text(std::string(bytes.begin(), bytes.end()), path);
}

Status check_object(const nlohmann::json& j, const std::string& where) {
  if (!j.is_object()) return Error{where + ": expected a JSON object, found " + std::string(j.type_name())};
  return Ok{};
}

Status check_keys(const nlohmann::json& j, std::initializer_list<const char*> allowed,
                  const std::string& where) {
  TERRALIGN_TRY(check_object(j, where));
  for (const auto& item : j.items()) {
    bool known = false;
    for (const char* a : allowed) known = known || item.key() == a;
    if (!known) {
      std::string list;
      for (const char* a : allowed) list += (list.empty() ? "" : ", ") + std::string(a);
      return Error{where + ": unknown key '" + item.key() + "' (allowed: " + list + ")"};
    }
  }
  return Ok{};
}

Result<double> json_number(const nlohmann::json& j, const char* key, const std::string& where) {
  if (!j.is_object() || !j.contains(key)) return Error{where + ": missing '" + key + "'"};
  const auto& v = j.at(key);
  if (!v.is_number()) return Error{where + ": '" + key + "' must be a number, found " + v.dump()};
  const double d = v.get<double>();
  if (!std::isfinite(d)) return Error{where + ": '" + key + "' is " + format_double(d) + ", not finite"};
  return d;
}

Result<int> json_int(const nlohmann::json& j, const char* key, const std::string& where) {
  TERRALIGN_TRY_ASSIGN(const double d, json_number(j, key, where));
  if (d != std::floor(d) || std::abs(d) > 1e9)
    return Error{where + ": '" + key + "' must be an integer, found " + format_double(d)};
  return static_cast<int>(d);
}

Result<std::string> json_string(const nlohmann::json& j, const char* key, const std::string& where) {
  if (!j.is_object() || !j.contains(key)) return Error{where + ": missing '" + key + "'"};
  const auto& v = j.at(key);
  if (!v.is_string()) return Error{where + ": '" + key + "' must be a string, found " + v.dump()};
  return v.get<std::string>();
}

Result<Eigen::Vector3d> json_vec3(const nlohmann::json& j, const char* key, const std::string& where) {
  if (!j.is_object() || !j.contains(key)) return Error{where + ": missing '" + key + "'"};
  const auto& v = j.at(key);
  if (!v.is_array() || v.size() != 3) return Error{where + ": '" + key + "' must be an array of 3 numbers"};
  Eigen::Vector3d out;
  for (int i = 0; i < 3; ++i) {
    if (!v[static_cast<std::size_t>(i)].is_number()) return Error{where + ": '" + key + "' must hold numbers"};
    out[i] = v[static_cast<std::size_t>(i)].get<double>();
    if (!std::isfinite(out[i])) return Error{where + ": '" + key + "' has a non-finite value"};
  }
  return out;
}

}  // namespace terralign::geo
