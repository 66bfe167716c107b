#include <terralign/geo/number_text.hpp>

#include <algorithm>
#include <charconv>
#include <clocale>
#include <cstdio>
#include <cstring>
#include <system_error>

namespace terralign::geo {

Result<double> parse_double(const std::string& token) {
  if (token.empty()) return Error{"empty text where a number was expected"};
  const char* first = token.data();
  const char* const last = first + token.size();
  while (first != last && (*first == ' ' || (*first >= '\t' && *first <= '\r'))) ++first;
  if (first != last && *first == '+') ++first;
  double v = 0;
  const auto [end, ec] = std::from_chars(first, last, v);
  if (ec == std::errc::result_out_of_range) return Error{"'" + token + "' is out of the range of a double"};
  if (ec != std::errc() || end != last) return Error{"'" + token + "' is not a number"};
  return v;
}

namespace {

// The C library's "%.*g" with the locale's decimal point turned back to '.' (printf groups no
// digits without the ' flag, so the point is all a locale changes). Not std::to_chars: its
// tables for a given precision would add 100 KB to the firmware's flash.
std::string printf_g(double v, int prec) {
  char buf[64];
  const int n = std::snprintf(buf, sizeof buf, "%.*g", prec, v);
  std::string s(buf, static_cast<std::size_t>(std::clamp(n, 0, static_cast<int>(sizeof buf) - 1)));
  const char* point = std::localeconv()->decimal_point;
  if (point && *point && std::strcmp(point, ".") != 0) {
    const std::size_t at = s.find(point);
    if (at != std::string::npos) s.replace(at, std::strlen(point), ".");
  }
  return s;
}

}  // namespace

std::string format_double(double v) {
  // The shortest precision that reads back the same; 17 digits always do.
  for (int prec = 1; prec < 17; ++prec) {
    std::string s = printf_g(v, prec);
    const auto back = parse_double(s);
    if (back.ok() && back.value() == v) return s;
  }
  return printf_g(v, 17);
}

}  // namespace terralign::geo
