// JSON helpers for geo's loaders (internal): parsing with line and column in errors, typed
// field access with named errors, and refusal of unknown keys.
#pragma once

#include <initializer_list>
#include <string>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include <terralign/geo/result.hpp>

namespace terralign::geo {

Result<nlohmann::json> parse_json_text(const std::string& text, const std::string& name);
Result<nlohmann::json> parse_json_file(const std::string& path);

// `where` names the object for messages ("camera.json", "map.json: layers[2]").
Status check_object(const nlohmann::json& j, const std::string& where);
Status check_keys(const nlohmann::json& j, std::initializer_list<const char*> allowed,
                  const std::string& where);
Result<double> json_number(const nlohmann::json& j, const char* key, const std::string& where);
Result<int> json_int(const nlohmann::json& j, const char* key, const std::string& where);
Result<std::string> json_string(const nlohmann::json& j, const char* key, const std::string& where);
Result<Eigen::Vector3d> json_vec3(const nlohmann::json& j, const char* key, const std::string& where);

}  // namespace terralign::geo
