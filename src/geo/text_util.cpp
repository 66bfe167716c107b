#include "text_util.hpp"

#include <cerrno>
#include <cstdio>
#include <cmath>
#include <cstdlib>

namespace terralign::geo {

Result<double> parse_double(const std::string& token) {
  if (token.empty()) return Error{"empty text where a number was expected"};
  errno = 0;
  char* end = nullptr;
  const double v = std::strtod(token.c_str(), &end);
  if (end != token.c_str() + token.size())
    return Error{"'" + token + "' is not a number"};
  if (errno == ERANGE && (v == HUGE_VAL || v == -HUGE_VAL))
    return Error{"'" + token + "' is out of the range of a double"};
  return v;
}

std::string format_double(double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  // Prefer the shortest form that reads back the same.
  for (int prec = 1; prec < 17; ++prec) {
    char shorter[64];
    std::snprintf(shorter, sizeof shorter, "%.*g", prec, v);
    if (std::strtod(shorter, nullptr) == v) return shorter;
  }
  return buf;
}

}  // namespace terralign::geo
