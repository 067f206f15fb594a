// Quantities given as text on the command line and in recipes: byte sizes, fractions and
// nonzero budgets. One parser each, so that "64K" or "2%" means the same in every flag.
#pragma once

#include <cstdint>
#include <string>

#include "format/status.h"

namespace ltb::stages {

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
