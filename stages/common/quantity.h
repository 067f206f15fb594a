// Quantities given as text on the command line, in recipes and in the view server's
// queries: decimal numbers, byte sizes, fractions and nonzero budgets. One parser each, so
// that "64K", "2%" or "-12.5" means the same in every flag and parameter.
#pragma once

#include <cstdint>
#include <string>

#include "format/status.h"

namespace ltb::stages {

// A real number written in decimal, and within [min, max]: an optional sign, digits with an
// optional point (at least one digit), an optional exponent (e or E, optional sign, digits),
// and nothing else: no spaces, no NUL or other byte after it, no hexadecimal ("0x10"), no
// "inf" or "nan". A number too large for a double (1e999) is out of range. The message
// quotes the text (bytes outside printable ASCII as \xNN) and the range; callers put the flag
// or parameter's name in front: "--rotate: \"1e20\" is outside [-1e+06, 1e+06]".
Result<double> ParseDecimal(const std::string& text, double min, double max);

// A value as messages show it: %.9g (enough for any float; -5.55e-17, not "-0.000000").
std::string MessageNumber(double v);

// Bytes: a number and an optional unit. K, M, G, T (also k, KiB, MiB, GiB, TiB) are powers
// of 1024; KB, MB, GB, TB powers of 1000; B or no unit: bytes. At least 1 byte, at most 8 EiB.
Result<uint64_t> ParseByteSize(const std::string& text);

// A fraction in (0, 1]: "0.05" or "5%".
Result<double> ParseFraction(const std::string& text);

// One budget of nonzeros for a whole matrix: a fraction of its elements ("0.02", "2%", or
// any number written with a point or an exponent), a count ("150000"), or a size with a
// unit of ParseByteSize ("64MiB", "64K"), at 8 bytes per nonzero.
struct Budget {
  enum class Kind { kFraction, kCount, kBytes };
  Kind kind = Kind::kCount;
  double value = 0;  // the fraction, the count or the bytes
};
Result<Budget> ParseBudget(const std::string& text);

// The budget as a number of nonzeros of a rows × cols matrix (at most all of them).
uint64_t BudgetNonzeros(const Budget& budget, uint64_t rows, uint64_t cols);

}  // namespace ltb::stages
