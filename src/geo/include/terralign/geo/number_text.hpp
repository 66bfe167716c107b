// Numbers read from and written to text the same way whatever the process's locale.
//
// A program that embeds terralign may set a locale with a decimal comma (setlocale(LC_ALL,
// "de_DE.UTF-8"), or std::locale::global with one). Before session 82 strtod then read the
// shipped weight file's "# max-disagreement-px 1.25" as 1 and refused the file, so the learned
// tracker could not be set up. These read through std::from_chars, which the C++ standard
// defines in the "C" locale's terms whatever is set, and write the C library's "%g" with the
// locale's decimal point turned back to '.'.
#pragma once

#include <string>
#include <vector>

#include <terralign/geo/result.hpp>

namespace terralign::geo {

// Parses a whole token as a double: leading white space and a leading '+' are skipped, as
// strtod skips them; "nan" and "inf" parse (the caller decides); a value beyond a double's
// range, either way, is an error.
Result<double> parse_double(const std::string& token);
// Parses a whole token as a base-10 integer, with parse_double's leading white space and '+';
// a value beyond a long long's range is an error.
Result<long long> parse_integer(const std::string& token);
// The numbers of `text` split at `separator`, each a whole token through parse_double. A
// blank separator (' ') splits at runs of white space and keeps no empty field; any other
// keeps them, so "700:" is an error, not one number.
Result<std::vector<double>> parse_numbers(const std::string& text, char separator);
// The shortest "%g"-style text ("C" locale) that reads back as the same double, a whole number
// below 1e15 written in full ("60", not "6e+01").
std::string format_double(double v);

}  // namespace terralign::geo
