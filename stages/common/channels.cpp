#include "stages/common/channels.h"

#include <filesystem>

#include "format/io/container_reader.h"

namespace ltb::stages {

namespace fs = std::filesystem;

const char* ChannelName(int channel) { return channel == 0 ? "r" : channel == 1 ? "g" : "b"; }

std::string ChannelPath(const std::string& set_path, int channel) {
  const fs::path p(set_path);
  return (p.parent_path() / (p.stem().string() + "." + ChannelName(channel) + p.extension().string())).string();
}

Result<std::vector<std::string>> ChannelFiles(const std::string& path) {
  std::error_code ec;
  if (fs::exists(path, ec)) return std::vector<std::string>{};
  std::vector<std::string> files;
  int present = -1;
  for (int c = 0; c < kChannels; ++c) {
    files.push_back(ChannelPath(path, c));
    if (present < 0 && fs::exists(files.back(), ec)) present = c;
  }
  if (present < 0) return std::vector<std::string>{};
  for (int c = 0; c < kChannels; ++c) {
    if (!fs::exists(files[c], ec)) {
      return NotFound(path + ": names the channel set " + files[present] + ", ... but " + files[c] + " (channel " +
                      ChannelName(c) + ") does not exist; bake it with sample --channel " + ChannelName(c) +
                      " (docs/COLOUR.md)");
    }
    LTB_ASSIGN_OR_RETURN(io::ContainerReader r, io::ContainerReader::Open(files[c]));
    const nlohmann::json& j = r.metadata().json;
    const std::string name =
        j.contains("channel") && j["channel"].is_object() ? j["channel"].value("name", std::string()) : std::string();
    if (name != ChannelName(c)) {
      return InvalidArgument(files[c] + ": holds " + (name.empty() ? "no colour channel" : "channel " + name) +
                             ", not channel " + ChannelName(c) + " of the set " + path + " (with " + files[present] +
                             "); rebake it with sample --channel " + ChannelName(c));
    }
  }
  return files;
}

}  // namespace ltb::stages
