// Status and result types for everything that can fail on bad input.
//
// Loaders and parsers return Result<T>: a value, or an Error whose message names the
// thing (file, key, tensor), the offending value and what was allowed. No exceptions
// cross a terralign API.
#pragma once

#include <string>
#include <utility>
#include <variant>

#include <terralign/geo/assert.hpp>

namespace terralign {

struct Error {
  std::string message;
};

// Prefixes an error with the context it happened in ("map.json: " + message).
inline Error with_context(const std::string& context, Error e) {
  return Error{context + ": " + e.message};
}

template <class T>
class [[nodiscard]] Result {
 public:
  Result(T value) : v_(std::move(value)) {}          // NOLINT: implicit on purpose
  Result(Error error) : v_(std::move(error)) {}      // NOLINT: implicit on purpose

  bool ok() const { return v_.index() == 0; }
  explicit operator bool() const { return ok(); }

  T& value() & {
    TERRALIGN_ASSERT(ok(), "Result::value() on an error");
    return std::get<0>(v_);
  }
  const T& value() const& {
    TERRALIGN_ASSERT(ok(), "Result::value() on an error");
    return std::get<0>(v_);
  }
  T&& value() && {
    TERRALIGN_ASSERT(ok(), "Result::value() on an error");
    return std::get<0>(std::move(v_));
  }
  T* operator->() { return &value(); }
  const T* operator->() const { return &value(); }
  T& operator*() & { return value(); }
  const T& operator*() const& { return value(); }

  const Error& error() const {
    TERRALIGN_ASSERT(!ok(), "Result::error() on a value");
    return std::get<1>(v_);
  }

 private:
  std::variant<T, Error> v_;
};

// For operations that return nothing but may fail.
struct Ok {};
using Status = Result<Ok>;

}  // namespace terralign

// Early return of an error from a function that returns Result<...> or Status.
#define TERRALIGN_TRY_ASSIGN(lhs, expr)                  \
  auto TERRALIGN_CONCAT_(res_, __LINE__) = (expr);       \
  if (!TERRALIGN_CONCAT_(res_, __LINE__).ok())           \
    return TERRALIGN_CONCAT_(res_, __LINE__).error();    \
  lhs = std::move(TERRALIGN_CONCAT_(res_, __LINE__)).value()

#define TERRALIGN_TRY(expr)                               \
  do {                                                    \
    auto res_try_ = (expr);                               \
    if (!res_try_.ok()) return res_try_.error();          \
  } while (0)

#define TERRALIGN_CONCAT_INNER_(a, b) a##b
#define TERRALIGN_CONCAT_(a, b) TERRALIGN_CONCAT_INNER_(a, b)
