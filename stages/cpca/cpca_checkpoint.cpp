#include "stages/cpca/cpca_checkpoint.h"

#include <cstdio>
#include <cstring>

#include "format/bytes.h"
#include "format/io/atomic_file.h"
#include "format/io/file.h"
#include "format/json_text.h"

namespace ltb::stages {

using namespace ltb::format;

namespace {
constexpr char kMagic[8] = {'L', 'T', 'B', 'C', 'P', 'C', 'A', '1'};
}

Status WriteCpcaCheckpoint(const std::string& path, const CpcaCheckpoint& cp) {
  const std::string header = JsonText(cp.header);
  std::vector<std::byte> buf(8 + 8 + header.size() + 8 + cp.values.size() * 8 + 8);
  std::byte* p = buf.data();
  std::memcpy(p, kMagic, 8);
  StoreU64(p + 8, header.size());
  std::memcpy(p + 16, header.data(), header.size());
  p += 16 + header.size();
  StoreU64(p, cp.values.size());
  if (!cp.values.empty()) std::memcpy(p + 8, cp.values.data(), cp.values.size() * 8);
  p += 8 + cp.values.size() * 8;
  StoreU64(p, Checksum(ByteSpan(buf.data(), p - buf.data())));
  return io::WriteFileAtomically(path, buf);
}

Result<std::optional<CpcaCheckpoint>> ReadCpcaCheckpoint(const std::string& path, uint64_t max_values) {
  if (!io::PathExists(path)) return std::optional<CpcaCheckpoint>{};
  LTB_ASSIGN_OR_RETURN(io::File f, io::File::Open(path, io::File::Mode::kRead));
  LTB_ASSIGN_OR_RETURN(uint64_t size, f.Size());
  const uint64_t cap = 64 + (1ull << 20) + max_values * 8;
  if (size < 32 || size > cap) {
    return DataLoss(path + ": checkpoint of " + std::to_string(size) + " bytes is outside 32.." + std::to_string(cap) +
                    "; delete it to start the cpca run afresh");
  }
  std::vector<std::byte> buf(size);
  LTB_RETURN_IF_ERROR(f.ReadAt(0, buf));
  auto bad = [&](const std::string& what) {
    return DataLoss(path + ": damaged checkpoint (" + what + "); delete it to start the cpca run afresh");
  };
  if (std::memcmp(buf.data(), kMagic, 8) != 0) return bad("wrong magic");
  const uint64_t want = LoadU64(buf.data() + size - 8);
  const uint64_t got = Checksum(ByteSpan(buf.data(), size - 8));
  if (want != got) return bad("checksum expected=" + Hex64(want) + ", actual=" + Hex64(got));
  const uint64_t hlen = LoadU64(buf.data() + 8);
  if (hlen > size - 32) return bad("header length " + std::to_string(hlen));
  CpcaCheckpoint cp;
  auto header = ParseJson(std::string_view(reinterpret_cast<const char*>(buf.data() + 16), hlen));
  if (!header.ok() || !header->is_object()) return bad("header is not a JSON object");
  cp.header = std::move(*header);
  const uint64_t nv = LoadU64(buf.data() + 16 + hlen);
  if (nv > max_values || 16 + hlen + 8 + nv * 8 + 8 != size) return bad("value count " + std::to_string(nv));
  cp.values.resize(nv);
  if (nv) std::memcpy(cp.values.data(), buf.data() + 24 + hlen, nv * 8);
  return std::optional<CpcaCheckpoint>{std::move(cp)};
}

}  // namespace ltb::stages
