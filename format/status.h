// Status and Result<T>: the one error currency of ltbake libraries.
// A Status carries a code and a message that grows context at each layer
// ("rows.ltm: chunk 17: checksum mismatch: expected=0x.., actual=0x..").
#pragma once

#include <optional>
#include <string>
#include <utility>
#include <variant>

namespace ltb {

enum class StatusCode {
  kOk = 0,
  kInvalidArgument,     // bad user input (flags, values, files that are not what they claim)
  kNotFound,            // a path or a chunk that does not exist
  kDataLoss,            // corruption: checksum mismatch, truncated structure
  kFailedPrecondition,  // input in the wrong state (incomplete file, wrong layout)
  kUnimplemented,       // a newer format feature this build cannot read
  kIo,                  // a failed system call
  kCancelled,           // interrupted by a signal; committed state is kept
  kInternal,            // a bug in ltbake
};

const char* StatusCodeName(StatusCode code);

class [[nodiscard]] Status {
 public:
  Status() = default;
  Status(StatusCode code, std::string message) : code_(code), message_(std::move(message)) {}

  static Status Ok() { return Status(); }
  bool ok() const { return code_ == StatusCode::kOk; }
  StatusCode code() const { return code_; }
  const std::string& message() const { return message_; }

  // Returns a copy whose message is "context: message".
  Status WithContext(const std::string& context) const {
    if (ok()) return *this;
    return Status(code_, context + ": " + message_);
  }
  std::string ToString() const;

 private:
  StatusCode code_ = StatusCode::kOk;
  std::string message_;
};

Status InvalidArgument(std::string message);
Status NotFound(std::string message);
Status DataLoss(std::string message);
Status FailedPrecondition(std::string message);
Status Unimplemented(std::string message);
Status Internal(std::string message);
Status Cancelled(std::string message);
// An I/O error: appends strerror(errnum).
Status IoError(const std::string& what, int errnum);

template <typename T>
class [[nodiscard]] Result {
 public:
  Result(T value) : value_(std::move(value)) {}          // NOLINT(implicit)
  Result(Status status) : status_(std::move(status)) {}  // NOLINT(implicit)

  bool ok() const { return status_.ok(); }
  const Status& status() const { return status_; }
  T& value() & { return *value_; }
  const T& value() const& { return *value_; }
  T&& value() && { return std::move(*value_); }
  T* operator->() { return &*value_; }
  const T* operator->() const { return &*value_; }
  T& operator*() { return *value_; }
  const T& operator*() const { return *value_; }

 private:
  Status status_;
  std::optional<T> value_;
};

}  // namespace ltb

#define LTB_CONCAT_INNER(a, b) a##b
#define LTB_CONCAT(a, b) LTB_CONCAT_INNER(a, b)

// Returns the status from the enclosing function when it is not ok.
#define LTB_RETURN_IF_ERROR(expr)              \
  do {                                         \
    ::ltb::Status ltb_status_ = (expr);        \
    if (!ltb_status_.ok()) return ltb_status_; \
  } while (0)

#define LTB_ASSIGN_OR_RETURN_IMPL(tmp, lhs, expr) \
  auto tmp = (expr);                              \
  if (!tmp.ok()) return tmp.status();             \
  lhs = std::move(tmp).value()

// LTB_ASSIGN_OR_RETURN(auto x, MakeX()); returns the status on failure.
#define LTB_ASSIGN_OR_RETURN(lhs, expr) LTB_ASSIGN_OR_RETURN_IMPL(LTB_CONCAT(ltb_result_, __LINE__), lhs, expr)
