#include "storage/sample_codec.h"

#include <bit>
#include <cmath>
#include <cstring>

#include "absl/strings/str_format.h"
#include "util/str_util.h"

namespace imucal::storage {
namespace {

constexpr uint8_t kFlagTemp = 0x01;
constexpr uint8_t kKnownFlags = kFlagTemp;
constexpr size_t kBaseFields = 7;  // t, ax, ay, az, gx, gy, gz
constexpr std::array<const char*, 8> kFieldNames = {"t_s", "ax", "ay", "az",
                                                    "gx",  "gy", "gz", "temp"};

void PutU32(uint32_t v, char* out) {
  for (int i = 0; i < 4; ++i) out[i] = static_cast<char>((v >> (8 * i)) & 0xff);
}

uint32_t GetU32(const char* in) {
  uint32_t v = 0;
  for (int i = 0; i < 4; ++i)
    v |= static_cast<uint32_t>(static_cast<unsigned char>(in[i])) << (8 * i);
  return v;
}

void PutF64(double d, char* out) {
  const uint64_t v = std::bit_cast<uint64_t>(d);
  for (int i = 0; i < 8; ++i) out[i] = static_cast<char>((v >> (8 * i)) & 0xff);
}

double GetF64(const char* in) {
  uint64_t v = 0;
  for (int i = 0; i < 8; ++i)
    v |= static_cast<uint64_t>(static_cast<unsigned char>(in[i])) << (8 * i);
  return std::bit_cast<double>(v);
}

absl::Status Corrupt(size_t offset, std::string_view what) {
  return absl::DataLossError(Cat("sample batch: offset ", offset, ": ", what));
}

struct Header {
  bool has_temp = false;
  size_t fields = kBaseFields;
  int64_t count = 0;
};

absl::StatusOr<Header> ReadHeader(std::string_view payload) {
  if (payload.size() < kSampleHeaderBytes) {
    return Corrupt(payload.size(), Cat("truncated header (", payload.size(), " of ",
                                       kSampleHeaderBytes, " bytes)"));
  }
  const auto version = static_cast<uint8_t>(payload[0]);
  if (version != kSampleCodecVersion) {
    return Corrupt(
        0, Cat("unknown format version ", version, " (expected ", kSampleCodecVersion, ")"));
  }
  const auto flags = static_cast<uint8_t>(payload[1]);
  if ((flags & ~kKnownFlags) != 0) {
    return Corrupt(1, absl::StrFormat("unknown flag bits 0x%02x", flags & ~kKnownFlags));
  }
  Header h;
  h.has_temp = (flags & kFlagTemp) != 0;
  h.fields = kBaseFields + (h.has_temp ? 1 : 0);
  h.count = GetU32(payload.data() + 2);
  // count < 2^32 and fields <= 8, so this cannot overflow a 64-bit size_t.
  const size_t expected = kSampleHeaderBytes + static_cast<size_t>(h.count) * h.fields * 8;
  if (payload.size() < expected) {
    return Corrupt(payload.size(), Cat("truncated: the header says ", h.count, " samples (",
                                       expected, " bytes), got ", payload.size(), " bytes"));
  }
  if (payload.size() > expected) {
    return Corrupt(expected,
                   Cat(payload.size() - expected, " unexpected bytes after ", h.count, " samples"));
  }
  return h;
}

// Validates every sample and hands it to `visit(const ImuSample&)`.
template <typename Visit>
absl::StatusOr<EncodedBatchInfo> Walk(std::string_view payload, Visit visit) {
  absl::StatusOr<Header> h = ReadHeader(payload);
  if (!h.ok()) return h.status();
  EncodedBatchInfo info;
  info.count = h->count;
  info.has_temp = h->has_temp;
  const char* p = payload.data() + kSampleHeaderBytes;
  double v[8];
  for (int64_t i = 0; i < h->count; ++i) {
    const size_t record_offset = kSampleHeaderBytes + static_cast<size_t>(i) * h->fields * 8;
    for (size_t f = 0; f < h->fields; ++f, p += 8) {
      v[f] = GetF64(p);
      if (!std::isfinite(v[f])) {
        return Corrupt(record_offset + f * 8,
                       Cat("sample ", i, " ", kFieldNames[f], " is not finite"));
      }
    }
    if (i > 0 && !(v[0] > info.last_t_s)) {
      return Corrupt(record_offset,
                     absl::StrFormat("sample %d t_s %.9g does not increase (previous %.9g)", i,
                                     v[0], info.last_t_s));
    }
    if (i == 0) info.first_t_s = v[0];
    info.last_t_s = v[0];
    ImuSample s;
    s.t_s = v[0];
    s.accel = {v[1], v[2], v[3]};
    s.gyro = {v[4], v[5], v[6]};
    if (h->has_temp) s.temp = v[7];
    visit(s);
  }
  return info;
}

absl::Status BadSample(size_t index, std::string_view what) {
  return absl::InvalidArgumentError(Cat("sample ", index, ": ", what));
}

}  // namespace

absl::StatusOr<std::string> EncodeSamples(std::span<const ImuSample> samples) {
  if (samples.size() > std::numeric_limits<uint32_t>::max()) {
    return absl::InvalidArgumentError(Cat("too many samples in one batch: ", samples.size()));
  }
  const bool has_temp = !samples.empty() && !std::isnan(samples[0].temp);
  const size_t fields = kBaseFields + (has_temp ? 1 : 0);
  std::string out(kSampleHeaderBytes + samples.size() * fields * 8, '\0');
  out[0] = static_cast<char>(kSampleCodecVersion);
  out[1] = static_cast<char>(has_temp ? kFlagTemp : 0);
  PutU32(static_cast<uint32_t>(samples.size()), out.data() + 2);
  char* p = out.data() + kSampleHeaderBytes;
  for (size_t i = 0; i < samples.size(); ++i) {
    const ImuSample& s = samples[i];
    if (std::isnan(s.temp) == has_temp) {
      return BadSample(i, has_temp ? "no temperature, but sample 0 has one"
                                   : "a temperature, but sample 0 has none");
    }
    const double v[8] = {s.t_s,     s.accel[0], s.accel[1], s.accel[2],
                         s.gyro[0], s.gyro[1],  s.gyro[2],  s.temp};
    for (size_t f = 0; f < fields; ++f, p += 8) {
      if (!std::isfinite(v[f])) return BadSample(i, Cat(kFieldNames[f], " is not finite"));
      PutF64(v[f], p);
    }
    if (i > 0 && !(s.t_s > samples[i - 1].t_s)) {
      return BadSample(i, absl::StrFormat("t_s %.9g does not increase (previous %.9g)", s.t_s,
                                          samples[i - 1].t_s));
    }
  }
  return out;
}

absl::StatusOr<EncodedBatchInfo> InspectSamples(std::string_view payload) {
  return Walk(payload, [](const ImuSample&) {});
}

absl::StatusOr<std::vector<ImuSample>> DecodeSamples(std::string_view payload) {
  std::vector<ImuSample> out;
  if (absl::Status s = DecodeSamplesInto(payload, &out); !s.ok()) return s;
  return out;
}

absl::Status DecodeSamplesInto(std::string_view payload, std::vector<ImuSample>* out) {
  const size_t old_size = out->size();
  if (payload.size() >= kSampleHeaderBytes) {
    // Reserve from the header only when the length agrees with it (garbage must not make us
    // allocate gigabytes); ReadHeader reports the mismatch otherwise.
    if (absl::StatusOr<Header> h = ReadHeader(payload); h.ok()) {
      out->reserve(old_size + static_cast<size_t>(h->count));
    }
  }
  absl::StatusOr<EncodedBatchInfo> info =
      Walk(payload, [out](const ImuSample& s) { out->push_back(s); });
  if (!info.ok()) {
    out->resize(old_size);
    return info.status();
  }
  return absl::OkStatus();
}

}  // namespace imucal::storage
