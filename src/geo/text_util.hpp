// Number parsing and formatting for error messages (internal to geo).
#pragma once

#include <string>

#include <terralign/geo/result.hpp>

namespace terralign::geo {

// Parses a whole token as a double ("nan" and "inf" parse; the caller decides).
Result<double> parse_double(const std::string& token);
// Shortest round-tripping text of a double, for messages.
std::string format_double(double v);

}  // namespace terralign::geo
