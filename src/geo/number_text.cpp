#include <terralign/geo/number_text.hpp>

#include <algorithm>
#include <charconv>
#include <clocale>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <system_error>
#include <type_traits>

namespace terralign::geo {

namespace {

bool is_blank(char c) { return c == ' ' || (c >= '\t' && c <= '\r'); }

// std::from_chars over the whole token after strtod's leading white space and '+'.
template <class T>
Result<T> parse_whole(const std::string& token, const char* what) {
  if (token.empty()) return Error{std::string("empty text where ") + what + " was expected"};
  const char* first = token.data();
  const char* const last = first + token.size();
  while (first != last && is_blank(*first)) ++first;
  if (first != last && *first == '+') ++first;
  T v{};
  const auto [end, ec] = std::from_chars(first, last, v);
  if (ec == std::errc::result_out_of_range)
    return Error{"'" + token + "' is out of the range of " + (std::is_integral_v<T> ? "a long long" : "a double")};
  if (ec != std::errc() || end != last) return Error{"'" + token + "' is not " + what};
  return v;
}

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

// "%g" writes a number with fewer significant digits than its exponent in exponent form: 60 as
// "6e+01", 1370 as "1.37e+03". Such a number below 1e15 is a whole number (its shortest
// digits read back as an integer below 2^53, which a double holds exactly), and is written
// in full, as a reader expects: "60", "1370". Larger ones and small ones keep "%g"'s form.
std::string whole_in_full(const std::string& shortest, double v) {
  const std::size_t e = shortest.find('e');
  if (e == std::string::npos || shortest[e + 1] != '+' || !(std::abs(v) < 1e15)) return shortest;
  const int exponent = std::atoi(shortest.c_str() + e + 2);
  std::string s = printf_g(v, exponent + 1);
  const auto back = parse_double(s);
  return back.ok() && back.value() == v ? s : shortest;
}

}  // namespace

Result<double> parse_double(const std::string& token) { return parse_whole<double>(token, "a number"); }

Result<long long> parse_integer(const std::string& token) { return parse_whole<long long>(token, "an integer"); }

Result<std::vector<double>> parse_numbers(const std::string& text, char separator) {
  std::vector<double> out;
  std::size_t a = 0;
  while (a <= text.size()) {
    if (separator == ' ') {
      while (a < text.size() && is_blank(text[a])) ++a;
      if (a == text.size()) break;
    }
    std::size_t b = a;
    while (b < text.size() && (separator == ' ' ? !is_blank(text[b]) : text[b] != separator)) ++b;
    auto v = parse_double(text.substr(a, b - a));
    if (!v.ok()) return v.error();
    out.push_back(v.value());
    a = b + 1;
  }
  return out;
}

std::string format_double(double v) {
  // The shortest precision that reads back the same; 17 digits always do.
  for (int prec = 1; prec < 17; ++prec) {
    std::string s = printf_g(v, prec);
    const auto back = parse_double(s);
    if (back.ok() && back.value() == v) return whole_in_full(s, v);
  }
  return printf_g(v, 17);
}

}  // namespace terralign::geo
