#include "importers/mcap.h"

#include <fcntl.h>
#include <lz4frame.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>
#include <zlib.h>
#include <zstd.h>

#include <algorithm>
#include <cerrno>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <set>
#include <span>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "importers/registry.h"
#include "importers/ros_imu.h"
#include "importers/rosbag2.h"
#include "util/str_util.h"

namespace imucal::importers {
namespace {

constexpr uint8_t kOpFooter = 0x02;
constexpr uint8_t kOpSchema = 0x03;
constexpr uint8_t kOpChannel = 0x04;
constexpr uint8_t kOpMessage = 0x05;
constexpr uint8_t kOpChunk = 0x06;
constexpr uint8_t kOpChunkIndex = 0x08;
constexpr uint8_t kOpDataEnd = 0x0F;
// opcode u8 + content length u64.
constexpr size_t kRecordPrefix = 9;
// The footer's content: summary_start, summary_offset_start, summary_crc.
constexpr size_t kFooterContent = 8 + 8 + 4;
// A chunk's records are decompressed into memory; rosbag2 writes chunks of ~1 MB (its
// chunk_size default is 768 KiB), so a declared size past this is a damaged file, not data.
constexpr uint64_t kMaxChunkBytes = uint64_t{1} << 30;

// Bounds-checked little-endian reading of one record's content; `base` is the content's offset
// in the file (for errors), `what` the record it is.
class Cursor {
 public:
  Cursor(std::string_view bytes, uint64_t base, std::string_view what)
      : bytes_(bytes), base_(base), what_(what) {}

  template <typename T>
  absl::Status Int(std::string_view field, T* out) {
    if (absl::Status s = Need(sizeof(T), field); !s.ok()) return s;
    T value = 0;
    for (size_t i = 0; i < sizeof(T); ++i) {
      value |=
          static_cast<T>(static_cast<T>(static_cast<unsigned char>(bytes_[pos_ + i])) << (8 * i));
    }
    pos_ += sizeof(T);
    *out = value;
    return absl::OkStatus();
  }
  // A u32-length-prefixed string, or (wide) a u64-length-prefixed byte field.
  absl::Status Bytes(std::string_view field, std::string_view* out, bool wide = false) {
    uint64_t length = 0;
    if (wide) {
      if (absl::Status s = Int(field, &length); !s.ok()) return s;
    } else {
      uint32_t length32 = 0;
      if (absl::Status s = Int(field, &length32); !s.ok()) return s;
      length = length32;
    }
    if (absl::Status s = Need(length, field); !s.ok()) return s;
    *out = bytes_.substr(pos_, length);
    pos_ += length;
    return absl::OkStatus();
  }
  absl::Status String(std::string_view field, std::string* out) {
    std::string_view view;
    if (absl::Status s = Bytes(field, &view); !s.ok()) return s;
    out->assign(view);
    return absl::OkStatus();
  }
  std::string_view Rest() {
    std::string_view rest = bytes_.substr(pos_);
    pos_ = bytes_.size();
    return rest;
  }
  uint64_t offset() const { return base_ + pos_; }

 private:
  absl::Status Need(uint64_t size, std::string_view field) const {
    if (size <= bytes_.size() - pos_) return absl::OkStatus();
    return absl::InvalidArgumentError(Cat("byte ", base_ + pos_, ": ", what_, " ends inside ",
                                          field, " (needs ", size, " bytes, ", bytes_.size() - pos_,
                                          " left)"));
  }

  std::string_view bytes_;
  uint64_t base_;
  std::string_view what_;
  size_t pos_ = 0;
};

std::string_view OpName(uint8_t op) {
  switch (op) {
    case kOpSchema:
      return "schema record";
    case kOpChannel:
      return "channel record";
    case kOpMessage:
      return "message record";
    case kOpChunk:
      return "chunk record";
    case kOpChunkIndex:
      return "chunk index record";
    default:
      return "record";
  }
}

// Calls `visit(opcode, content, content_offset)` for each record of `region` (which starts at
// file offset `base`) until the region ends, `visit` returns an error, or (stop_at_data_end) a
// Data End record. Records must fit in the region.
using RecordVisitor = std::function<absl::Status(uint8_t, std::string_view, uint64_t)>;
absl::Status ForEachRecord(std::string_view region, uint64_t base, std::string_view where,
                           const RecordVisitor& visit, bool stop_at_data_end = false) {
  size_t pos = 0;
  while (pos < region.size()) {
    if (region.size() - pos < kRecordPrefix) {
      return absl::InvalidArgumentError(Cat("byte ", base + pos, ": ", where,
                                            " ends inside a record header (", region.size() - pos,
                                            " bytes left)"));
    }
    const uint8_t op = static_cast<uint8_t>(region[pos]);
    uint64_t length = 0;
    for (int i = 0; i < 8; ++i)
      length |= uint64_t{static_cast<unsigned char>(region[pos + 1 + i])} << (8 * i);
    const size_t content = pos + kRecordPrefix;
    if (length > region.size() - content) {
      return absl::InvalidArgumentError(Cat("byte ", base + pos, ": ", OpName(op), " of ", length,
                                            " bytes runs past the end of the ", where, " (",
                                            region.size() - content, " bytes left)"));
    }
    if (stop_at_data_end && (op == kOpDataEnd || op == kOpFooter)) return absl::OkStatus();
    if (absl::Status s = visit(op, region.substr(content, length), base + content); !s.ok())
      return s;
    pos = content + length;
  }
  return absl::OkStatus();
}

struct Channel {
  uint16_t schema_id = 0;
  std::string topic;
  std::string message_encoding;
};

// A chunk's header fields and its (still compressed) records.
struct ChunkRecord {
  uint64_t uncompressed_size = 0;
  uint32_t uncompressed_crc = 0;
  std::string compression;
  std::string_view records;
  uint64_t records_offset = 0;
};

absl::StatusOr<ChunkRecord> ParseChunk(std::string_view content, uint64_t offset) {
  Cursor c(content, offset, "chunk record");
  ChunkRecord chunk;
  uint64_t start_time = 0, end_time = 0;
  if (absl::Status s = c.Int("message_start_time", &start_time); !s.ok()) return s;
  if (absl::Status s = c.Int("message_end_time", &end_time); !s.ok()) return s;
  if (absl::Status s = c.Int("uncompressed_size", &chunk.uncompressed_size); !s.ok()) return s;
  if (absl::Status s = c.Int("uncompressed_crc", &chunk.uncompressed_crc); !s.ok()) return s;
  if (absl::Status s = c.String("compression", &chunk.compression); !s.ok()) return s;
  chunk.records_offset = c.offset() + 8;
  if (absl::Status s = c.Bytes("records", &chunk.records, /*wide=*/true); !s.ok()) return s;
  return chunk;
}

// Decompresses a zstd or LZ4-frame stream into `out`, growing it only as output is produced (a
// damaged header's uncompressed_size never allocates by itself), refusing more than `expected`.
template <typename Step>
absl::Status Inflate(std::string_view in, uint64_t expected, std::string* out, Step step) {
  out->clear();
  out->resize(std::min<uint64_t>(expected, std::max<uint64_t>(4096, 4 * in.size())));
  size_t in_pos = 0, out_pos = 0;
  while (true) {
    if (out_pos == out->size()) {
      if (out->size() >= expected) {
        // Full: the stream must be complete; one more step with no room says whether it is.
        std::string spare(1, '\0');
        size_t spare_pos = 0;
        absl::StatusOr<bool> done = step(in, &in_pos, &spare, &spare_pos);
        if (!done.ok()) return done.status();
        if (spare_pos > 0) return absl::InvalidArgumentError("more data than uncompressed_size");
        if (*done) return absl::OkStatus();
        return absl::InvalidArgumentError("the compressed stream does not end");
      }
      out->resize(std::min<uint64_t>(expected, 2 * out->size()));
    }
    absl::StatusOr<bool> done = step(in, &in_pos, out, &out_pos);
    if (!done.ok()) return done.status();
    if (*done) {
      if (out_pos != expected) {
        return absl::InvalidArgumentError(
            Cat("decompresses to ", out_pos, " bytes, not the declared ", expected));
      }
      return absl::OkStatus();
    }
    if (in_pos == in.size() && out_pos < out->size()) {
      return absl::InvalidArgumentError("the compressed stream is truncated");
    }
  }
}

absl::Status InflateZstd(std::string_view in, uint64_t expected, std::string* out) {
  std::unique_ptr<ZSTD_DCtx, size_t (*)(ZSTD_DCtx*)> ctx(ZSTD_createDCtx(), ZSTD_freeDCtx);
  if (ctx == nullptr) return absl::ResourceExhaustedError("zstd: out of memory");
  bool ended = false;
  return Inflate(in, expected, out,
                 [&](std::string_view src, size_t* in_pos, std::string* dst,
                     size_t* out_pos) -> absl::StatusOr<bool> {
                   if (ended) return src.size() == *in_pos;
                   ZSTD_inBuffer ib{src.data(), src.size(), *in_pos};
                   ZSTD_outBuffer ob{dst->data(), dst->size(), *out_pos};
                   const size_t r = ZSTD_decompressStream(ctx.get(), &ob, &ib);
                   if (ZSTD_isError(r)) {
                     return absl::InvalidArgumentError(Cat("zstd: ", ZSTD_getErrorName(r)));
                   }
                   *in_pos = ib.pos;
                   *out_pos = ob.pos;
                   // r == 0: a frame ended; the chunk is one frame (more input: trailing bytes).
                   if (r == 0) {
                     ended = true;
                     if (ib.pos != src.size()) {
                       return absl::InvalidArgumentError("zstd: bytes after the frame");
                     }
                     return true;
                   }
                   return false;
                 });
}

absl::Status InflateLz4(std::string_view in, uint64_t expected, std::string* out) {
  LZ4F_dctx* raw = nullptr;
  if (LZ4F_isError(LZ4F_createDecompressionContext(&raw, LZ4F_VERSION))) {
    return absl::ResourceExhaustedError("lz4: out of memory");
  }
  std::unique_ptr<LZ4F_dctx, size_t (*)(LZ4F_dctx*)> ctx(raw, LZ4F_freeDecompressionContext);
  bool ended = false;
  return Inflate(in, expected, out,
                 [&](std::string_view src, size_t* in_pos, std::string* dst,
                     size_t* out_pos) -> absl::StatusOr<bool> {
                   if (ended) return src.size() == *in_pos;
                   size_t src_size = src.size() - *in_pos;
                   size_t dst_size = dst->size() - *out_pos;
                   const size_t r = LZ4F_decompress(ctx.get(), dst->data() + *out_pos, &dst_size,
                                                    src.data() + *in_pos, &src_size, nullptr);
                   if (LZ4F_isError(r)) {
                     return absl::InvalidArgumentError(Cat("lz4: ", LZ4F_getErrorName(r)));
                   }
                   *in_pos += src_size;
                   *out_pos += dst_size;
                   if (r == 0) {
                     ended = true;
                     if (*in_pos != src.size()) {
                       return absl::InvalidArgumentError("lz4: bytes after the frame");
                     }
                     return true;
                   }
                   return false;
                 });
}

// The chunk's records, decompressed (into `buffer` when compressed) and CRC-checked.
absl::StatusOr<std::string_view> ChunkRecords(const ChunkRecord& chunk, uint64_t offset,
                                              std::string* buffer) {
  auto error = [&](std::string_view what) {
    return absl::InvalidArgumentError(Cat("byte ", offset, ": chunk of ", chunk.records.size(),
                                          " bytes (compression '", chunk.compression,
                                          "'): ", what));
  };
  if (chunk.uncompressed_size > kMaxChunkBytes) {
    return error(Cat("uncompressed_size ", chunk.uncompressed_size, " is over the ", kMaxChunkBytes,
                     "-byte limit"));
  }
  std::string_view records;
  if (chunk.compression.empty()) {
    if (chunk.records.size() != chunk.uncompressed_size) {
      return error(Cat("uncompressed_size says ", chunk.uncompressed_size, " bytes"));
    }
    records = chunk.records;
  } else {
    absl::Status s;
    if (chunk.compression == "zstd") {
      s = InflateZstd(chunk.records, chunk.uncompressed_size, buffer);
    } else if (chunk.compression == "lz4") {
      s = InflateLz4(chunk.records, chunk.uncompressed_size, buffer);
    } else {
      return error("unknown compression (known: none, zstd, lz4)");
    }
    if (!s.ok()) return error(std::string(s.message()));
    records = *buffer;
  }
  if (chunk.uncompressed_crc != 0) {
    // CRC-32 (ISO-HDLC, zlib's crc32), as the spec's uncompressed_crc.
    const uint32_t crc = static_cast<uint32_t>(
        crc32_z(0, reinterpret_cast<const Bytef*>(records.data()), records.size()));
    if (crc != chunk.uncompressed_crc) {
      return error(Cat("its records fail their CRC-32 (stored ", chunk.uncompressed_crc,
                       ", computed ", crc, ")"));
    }
  }
  return records;
}

// A file mapped read-only (munmap on destruction).
struct Mapping {
  void* data = MAP_FAILED;
  size_t size = 0;
  ~Mapping() {
    if (data != MAP_FAILED) ::munmap(data, size);
  }
};

}  // namespace

struct McapReader::Impl {
  std::string name;
  std::string_view bytes;
  Mapping mapping;
  // The data section: after the leading magic, up to the summary (or the footer).
  std::string_view data;
  bool has_summary = false;
  std::map<uint16_t, std::string> schemas;  // id -> name (the ROS type)
  std::map<uint16_t, Channel> channels;
  struct IndexedChunk {
    uint64_t offset;
    uint64_t length;
    std::set<uint16_t> channels;  // empty: the index does not say
  };
  std::vector<IndexedChunk> chunks;
  bool scanned = false;  // channels collected from the data section

  absl::Status Error(const absl::Status& s) const {
    return absl::Status(s.code(), Cat(name, ": ", s.message()));
  }

  absl::Status AddSchema(std::string_view content, uint64_t offset) {
    Cursor c(content, offset, "schema record");
    uint16_t id = 0;
    std::string schema_name;
    if (absl::Status s = c.Int("id", &id); !s.ok()) return s;
    if (absl::Status s = c.String("name", &schema_name); !s.ok()) return s;
    if (id != 0) schemas[id] = std::move(schema_name);  // id 0 is invalid: ignored (spec)
    return absl::OkStatus();
  }
  absl::Status AddChannel(std::string_view content, uint64_t offset) {
    Cursor c(content, offset, "channel record");
    uint16_t id = 0;
    Channel channel;
    if (absl::Status s = c.Int("id", &id); !s.ok()) return s;
    if (absl::Status s = c.Int("schema_id", &channel.schema_id); !s.ok()) return s;
    if (absl::Status s = c.String("topic", &channel.topic); !s.ok()) return s;
    if (absl::Status s = c.String("message_encoding", &channel.message_encoding); !s.ok()) return s;
    channels[id] = std::move(channel);
    return absl::OkStatus();
  }

  // Visits every record of the data section, the records inside chunks included.
  absl::Status ScanData(const RecordVisitor& visit) {
    std::string buffer;
    return ForEachRecord(
        data, kMcapMagic.size(), "data section",
        [&](uint8_t op, std::string_view content, uint64_t offset) -> absl::Status {
          if (op != kOpChunk) return visit(op, content, offset);
          return VisitChunk(content, offset, &buffer, visit);
        },
        /*stop_at_data_end=*/true);
  }
  absl::Status VisitChunk(std::string_view content, uint64_t offset, std::string* buffer,
                          const RecordVisitor& visit) {
    absl::StatusOr<ChunkRecord> chunk = ParseChunk(content, offset);
    if (!chunk.ok()) return chunk.status();
    absl::StatusOr<std::string_view> records = ChunkRecords(*chunk, offset, buffer);
    if (!records.ok()) return records.status();
    // Offsets inside a compressed chunk are not file offsets: errors there name the chunk's
    // records offset plus the position in the uncompressed records.
    return ForEachRecord(*records, chunk->records_offset,
                         Cat("chunk at byte ", offset - kRecordPrefix), visit);
  }

  absl::Status ReadSummary(uint64_t summary_start, uint64_t footer_offset) {
    const std::string_view summary = bytes.substr(summary_start, footer_offset - summary_start);
    return ForEachRecord(
        summary, summary_start, "summary section",
        [&](uint8_t op, std::string_view content, uint64_t offset) -> absl::Status {
          if (op == kOpSchema) return AddSchema(content, offset);
          if (op == kOpChannel) return AddChannel(content, offset);
          if (op != kOpChunkIndex) return absl::OkStatus();
          Cursor c(content, offset, "chunk index record");
          uint64_t start_time = 0, end_time = 0;
          IndexedChunk chunk;
          if (absl::Status s = c.Int("message_start_time", &start_time); !s.ok()) return s;
          if (absl::Status s = c.Int("message_end_time", &end_time); !s.ok()) return s;
          if (absl::Status s = c.Int("chunk_start_offset", &chunk.offset); !s.ok()) return s;
          if (absl::Status s = c.Int("chunk_length", &chunk.length); !s.ok()) return s;
          std::string_view map;
          if (absl::Status s = c.Bytes("message_index_offsets", &map); !s.ok()) return s;
          Cursor m(map, c.offset() - map.size(), "message_index_offsets");
          while (m.offset() < c.offset()) {
            uint16_t channel = 0;
            uint64_t index_offset = 0;
            if (absl::Status s = m.Int("channel id", &channel); !s.ok()) return s;
            if (absl::Status s = m.Int("offset", &index_offset); !s.ok()) return s;
            chunk.channels.insert(channel);
          }
          if (chunk.offset < kMcapMagic.size() || chunk.offset > data.size() + kMcapMagic.size() ||
              chunk.length > data.size() + kMcapMagic.size() - chunk.offset) {
            return absl::InvalidArgumentError(
                Cat("byte ", offset, ": chunk index points outside the data section (chunk at ",
                    chunk.offset, ", ", chunk.length, " bytes)"));
          }
          chunks.push_back(std::move(chunk));
          return absl::OkStatus();
        });
  }

  absl::Status Load() {
    if (bytes.size() < 2 * kMcapMagic.size() + kRecordPrefix + kFooterContent) {
      if (!bytes.starts_with(kMcapMagic)) {
        return absl::InvalidArgumentError("not an MCAP file (no MCAP magic at the start)");
      }
      return absl::InvalidArgumentError(Cat("byte 0: the file ends after ", bytes.size(),
                                            " bytes, before an MCAP footer (cut short?)"));
    }
    if (!bytes.starts_with(kMcapMagic)) {
      return absl::InvalidArgumentError("not an MCAP file (no MCAP magic at the start)");
    }
    const uint64_t footer_offset =
        bytes.size() - kMcapMagic.size() - kRecordPrefix - kFooterContent;
    const bool has_footer =
        bytes.ends_with(kMcapMagic) && static_cast<uint8_t>(bytes[footer_offset]) == kOpFooter;
    uint64_t summary_start = 0;
    if (has_footer) {
      Cursor c(bytes.substr(footer_offset + kRecordPrefix, kFooterContent),
               footer_offset + kRecordPrefix, "footer");
      if (absl::Status s = c.Int("summary_start", &summary_start); !s.ok()) return s;
      if (summary_start != 0 &&
          (summary_start < kMcapMagic.size() || summary_start > footer_offset)) {
        return absl::InvalidArgumentError(Cat("byte ", footer_offset, ": footer's summary_start ",
                                              summary_start, " is outside the file"));
      }
    }
    const uint64_t data_end = summary_start != 0 ? summary_start
                              : has_footer       ? footer_offset
                                                 : bytes.size();
    data = bytes.substr(kMcapMagic.size(), data_end - kMcapMagic.size());
    if (!has_footer) {
      // A recording cut short: the records up to the end must still be whole (ScanData says
      // where one is cut); the importer reads nothing of a file it cannot read to its end.
      absl::Status s =
          ScanData([](uint8_t, std::string_view, uint64_t) { return absl::OkStatus(); });
      if (!s.ok())
        return absl::InvalidArgumentError(
            Cat(s.message(), " (no MCAP footer: the recording was cut short?)"));
      return absl::InvalidArgumentError(
          Cat("byte ", bytes.size(), ": no MCAP footer and magic at the end (cut short?)"));
    }
    if (summary_start != 0) {
      has_summary = true;
      if (absl::Status s = ReadSummary(summary_start, footer_offset); !s.ok()) return s;
    }
    return absl::OkStatus();
  }

  absl::Status CollectChannels() {
    if (has_summary && !channels.empty()) return absl::OkStatus();
    if (scanned) return absl::OkStatus();
    scanned = true;
    return ScanData([&](uint8_t op, std::string_view content, uint64_t offset) -> absl::Status {
      if (op == kOpSchema) return AddSchema(content, offset);
      if (op == kOpChannel) return AddChannel(content, offset);
      return absl::OkStatus();
    });
  }
};

McapReader::McapReader(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
McapReader::~McapReader() = default;

absl::StatusOr<std::unique_ptr<McapReader>> McapReader::FromBytes(std::string_view bytes,
                                                                  std::string name) {
  auto impl = std::make_unique<Impl>();
  impl->name = std::move(name);
  impl->bytes = bytes;
  if (absl::Status s = impl->Load(); !s.ok()) return impl->Error(s);
  return std::unique_ptr<McapReader>(new McapReader(std::move(impl)));
}

absl::StatusOr<std::unique_ptr<McapReader>> McapReader::Open(const std::string& path) {
  auto impl = std::make_unique<Impl>();
  impl->name = path;
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return absl::ErrnoToStatus(errno, Cat(path, ": cannot open"));
  struct stat info;
  if (::fstat(fd, &info) != 0) {
    const int error = errno;
    ::close(fd);
    return absl::ErrnoToStatus(error, Cat(path, ": cannot read"));
  }
  if (info.st_size > 0) {
    impl->mapping.size = static_cast<size_t>(info.st_size);
    impl->mapping.data = ::mmap(nullptr, impl->mapping.size, PROT_READ, MAP_PRIVATE, fd, 0);
  }
  const int map_error = errno;
  ::close(fd);
  if (info.st_size > 0 && impl->mapping.data == MAP_FAILED)
    return absl::ErrnoToStatus(map_error, Cat(path, ": cannot read"));
  if (info.st_size > 0) {
    impl->bytes =
        std::string_view(static_cast<const char*>(impl->mapping.data), impl->mapping.size);
  }
  if (absl::Status s = impl->Load(); !s.ok()) return impl->Error(s);
  return std::unique_ptr<McapReader>(new McapReader(std::move(impl)));
}

bool McapReader::indexed() const { return impl_->has_summary && !impl_->chunks.empty(); }

absl::StatusOr<std::vector<BagTopic>> McapReader::Topics() {
  if (absl::Status s = impl_->CollectChannels(); !s.ok()) return impl_->Error(s);
  std::vector<BagTopic> topics;
  for (const auto& [id, channel] : impl_->channels) {
    const auto schema = impl_->schemas.find(channel.schema_id);
    BagTopic topic{channel.topic,
                   schema == impl_->schemas.end() ? std::string("(no schema)") : schema->second,
                   channel.message_encoding};
    const bool listed = std::any_of(topics.begin(), topics.end(),
                                    [&](const BagTopic& t) { return t.name == topic.name; });
    if (!listed) topics.push_back(std::move(topic));
  }
  return topics;
}

absl::Status McapReader::ReadTopic(std::string_view topic, ImuMessages* out) {
  Impl& m = *impl_;
  if (absl::Status s = m.CollectChannels(); !s.ok()) return m.Error(s);
  auto visit = [&](uint8_t op, std::string_view content, uint64_t offset) -> absl::Status {
    // Channels can also appear inside chunks (the linear scan also finds new ones here).
    if (op == kOpChannel) return m.AddChannel(content, offset);
    if (op == kOpSchema) return m.AddSchema(content, offset);
    if (op != kOpMessage) return absl::OkStatus();
    Cursor c(content, offset, "message record");
    uint16_t channel_id = 0;
    uint32_t sequence = 0;
    uint64_t log_time = 0, publish_time = 0;
    if (absl::Status s = c.Int("channel_id", &channel_id); !s.ok()) return s;
    const auto channel = m.channels.find(channel_id);
    if (channel == m.channels.end() || channel->second.topic != topic) return absl::OkStatus();
    if (absl::Status s = c.Int("sequence", &sequence); !s.ok()) return s;
    if (absl::Status s = c.Int("log_time", &log_time); !s.ok()) return s;
    if (absl::Status s = c.Int("publish_time", &publish_time); !s.ok()) return s;
    // Timestamps are u64 nanoseconds; ROS's fit in int64 until 2262.
    return out->Add(c.Rest(), static_cast<int64_t>(log_time), m.name, topic);
  };
  if (!indexed()) {
    if (absl::Status s = m.ScanData(visit); !s.ok()) return m.Error(s);
    return absl::OkStatus();
  }
  std::set<uint16_t> wanted;
  for (const auto& [id, channel] : m.channels)
    if (channel.topic == topic) wanted.insert(id);
  std::vector<const Impl::IndexedChunk*> chunks;
  for (const Impl::IndexedChunk& chunk : m.chunks) {
    const bool holds = chunk.channels.empty() ||
                       std::any_of(wanted.begin(), wanted.end(),
                                   [&](uint16_t id) { return chunk.channels.count(id) > 0; });
    if (holds) chunks.push_back(&chunk);
  }
  std::sort(chunks.begin(), chunks.end(),
            [](const auto* a, const auto* b) { return a->offset < b->offset; });
  std::string buffer;
  for (const Impl::IndexedChunk* chunk : chunks) {
    const std::string_view record = m.bytes.substr(chunk->offset, chunk->length);
    absl::Status s =
        ForEachRecord(record, chunk->offset, "indexed chunk",
                      [&](uint8_t op, std::string_view content, uint64_t offset) -> absl::Status {
                        if (op != kOpChunk) {
                          return absl::InvalidArgumentError(Cat("byte ", offset - kRecordPrefix,
                                                                ": the chunk index points at a ",
                                                                OpName(op), ", not a chunk"));
                        }
                        return m.VisitChunk(content, offset, &buffer, visit);
                      });
    if (!s.ok()) return m.Error(s);
  }
  return absl::OkStatus();
}

absl::StatusOr<core::Capture> ReadMcapImu(const std::string& path,
                                          const std::vector<std::string>& files,
                                          const ImportOptions& options,
                                          std::vector<std::string>* notes) {
  ImuMessages messages;
  std::string topic = options.topic;
  bool scanned = false;
  for (const std::string& file : files) {
    absl::StatusOr<std::unique_ptr<McapReader>> reader = McapReader::Open(file);
    if (!reader.ok()) return reader.status();
    absl::StatusOr<std::vector<BagTopic>> topics = (*reader)->Topics();
    if (!topics.ok()) return topics.status();
    // Split files each list their topics; the first file's choice holds for the rest.
    absl::StatusOr<BagTopic> chosen = ChooseImuTopic(*topics, topic, file);
    if (!chosen.ok()) return chosen.status();
    topic = chosen->name;
    scanned |= !(*reader)->indexed();
    if (absl::Status s = (*reader)->ReadTopic(topic, &messages); !s.ok()) return s;
  }
  messages.SortByBagTime();
  absl::StatusOr<core::Capture> capture =
      messages.ToCapture(path, topic, files.size(), options, notes);
  if (capture.ok() && scanned) {
    notes->push_back("no MCAP summary (or no chunk index): read by scanning the whole file");
  }
  return capture;
}

namespace {

class McapImporterImpl final : public CaptureImporter {
 public:
  std::string_view name() const override { return "mcap"; }
  std::string_view description() const override {
    return "ROS 2 MCAP file (.mcap; a bag directory is read by rosbag2), "
           "sensor_msgs/msg/Imu topic (--topic)";
  }
  absl::Status Sniff(std::span<const std::string> paths,
                     std::span<const std::string> heads) const override {
    if (paths.size() != 1) return absl::InvalidArgumentError("an MCAP file is one path");
    if (heads[0].starts_with(kMcapMagic)) return absl::OkStatus();
    return absl::InvalidArgumentError("no MCAP magic at the start");
  }
  absl::StatusOr<core::Capture> Import(const std::vector<std::string>& paths,
                                       const ImportOptions& options,
                                       std::vector<std::string>* used_paths,
                                       std::vector<std::string>* notes) const override {
    if (absl::Status s = CheckOnePath("mcap", "file", paths); !s.ok()) return s;
    *used_paths = paths;
    // A bag directory (--format mcap given for one): its metadata.yaml lists the files.
    if (std::filesystem::is_directory(paths[0])) return ReadRosbag2Imu(paths[0], options, notes);
    return ReadMcapImu(paths[0], paths, options, notes);
  }
};

}  // namespace

const CaptureImporter* McapImporter() {
  static const auto* const kImporter = new McapImporterImpl();
  return kImporter;
}

}  // namespace imucal::importers
