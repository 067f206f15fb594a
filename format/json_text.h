// JSON text in and out, in one place. nlohmann/json's parser and serializer are the costliest
// templates a source can instantiate: a file that parses and dumps compiles ~3x as long as one
// that only includes the header (7 s against 22 s under the sanitizers; bench/results/suite_times.md), and a
// library pays that once per compiler run. Every ltbake source goes through these two
// functions, compiled once, in format/json_text.cpp.
#pragma once
#include <nlohmann/json.hpp>
#include <string>
#include <string_view>

#include "format/status.h"

namespace ltb {

// The JSON value in `text`, or InvalidArgument with the parser's message (the line and column
// and what it read there) for the caller to prefix with the file it read.
Result<nlohmann::json> ParseJson(std::string_view text);

// `j` as text: compact when indent < 0 (no spaces), else one element a line indented by
// `indent` spaces. A string that is not valid UTF-8 (a name read from a hostile file) is
// written with U+FFFD for its bad bytes instead of throwing.
std::string JsonText(const nlohmann::json& j, int indent = -1);

}  // namespace ltb
