#include "stages/common/channels.h"

#include <filesystem>

#include "format/io/container_reader.h"
#include "format/json_text.h"

namespace ltb::stages {

namespace fs = std::filesystem;

const char* ChannelName(int channel) { return channel == 0 ? "r" : channel == 1 ? "g" : "b"; }

std::string SetMemberPath(const std::string& set_path, const std::string& name) {
  const fs::path p(set_path);
  return (p.parent_path() / (p.stem().string() + "." + name + p.extension().string())).string();
}

std::string ChannelPath(const std::string& set_path, int channel) {
  return SetMemberPath(set_path, ChannelName(channel));
}

namespace {

// The member name under metadata key `key` ("channel", or a colour factored bake's "term"),
// or "" when absent.
std::string MemberName(const nlohmann::json& j, const char* key = "channel") {
  return j.contains(key) && j[key].is_object() && j[key].contains("name") && j[key]["name"].is_string()
             ? j[key]["name"].get<std::string>()
             : std::string();
}

}  // namespace

std::string SetLeaf(const std::string& path) {
  std::error_code ec;
  if (fs::exists(path, ec)) return path;
  const std::string red = SetMemberPath(path, "r");
  return fs::exists(red, ec) ? red : path;
}

Result<std::vector<SetMember>> ChannelFiles(const std::string& path) {
  std::error_code ec;
  if (fs::exists(path, ec)) return std::vector<SetMember>{};
  // Which kind of set: the first member that exists names the others.
  std::vector<std::string> names;
  std::string first;
  for (const char* probe : {"r", "g", "b"}) {
    if (fs::exists(SetMemberPath(path, probe), ec)) {
      names = {"r", "g", "b"};
      first = SetMemberPath(path, probe);
      break;
    }
  }
  // A factored bake's terms X.k0.ltm ..., or in colour X.k0.r.ltm ... (each term a colour set,
  // the terms listed under "term" in its files).
  const std::string k0 = SetMemberPath(path, "k0");
  const bool colour_terms = names.empty() && !fs::exists(k0, ec) && SetLeaf(k0) != k0;
  const char* key = colour_terms ? "term" : "channel";
  if (names.empty() && (colour_terms || fs::exists(k0, ec))) {
    first = SetLeaf(k0);
    LTB_ASSIGN_OR_RETURN(io::ContainerReader r, io::ContainerReader::Open(first));
    const nlohmann::json& j = r.metadata().json;
    const nlohmann::json* list =
        j.contains(key) && j[key].is_object() && j[key].contains("names") ? &j[key]["names"] : nullptr;
    if (list == nullptr || !list->is_array() || list->empty() || list->size() > 64) {
      return InvalidArgument(first +
                             ": names no terms of a factored bake (\"channel\": {\"names\": [...]}); rebake "
                             "it with sample --factor K");
    }
    for (const auto& n : *list) {
      if (!n.is_string() || n.get<std::string>().empty() || n.get<std::string>().find('/') != std::string::npos) {
        return InvalidArgument(first + ": a set member name is " + JsonText(n) + ", not a plain name");
      }
      names.push_back(n.get<std::string>());
    }
  }
  if (names.empty()) return std::vector<SetMember>{};
  std::vector<SetMember> members;
  for (const std::string& name : names) {
    const std::string member = SetMemberPath(path, name), file = colour_terms ? SetLeaf(member) : member;
    if (!fs::exists(file, ec)) {
      return NotFound(path + ": names the set of " + first + ", but its member " + file + " (" + name +
                      ") does not exist; bake it (docs/COLOUR.md)");
    }
    LTB_ASSIGN_OR_RETURN(io::ContainerReader r, io::ContainerReader::Open(file));
    const std::string got = MemberName(r.metadata().json, key);
    const nlohmann::json& ch = r.metadata().json.value(key, nlohmann::json::object());
    if (got == name && first.find(".k0.") != std::string::npos && ch.value("names", nlohmann::json()) != names) {
      return InvalidArgument(file + ": is term " + name + " of a bake with " +
                             std::to_string(ch.value("names", nlohmann::json::array()).size()) + " terms, and " +
                             first + " of one with " + std::to_string(names.size()) +
                             "; every term of a set comes from one sample --factor K");
    }
    if (got != name) {
      return InvalidArgument(file + ": holds " + (got.empty() ? "no colour channel or term" : "member " + got) +
                             ", not " + name + " of the set " + path + " (with " + first +
                             "); rebake it (sample --channel or --factor)");
    }
    members.push_back({name, member});
  }
  return members;
}

}  // namespace ltb::stages
