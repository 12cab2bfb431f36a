#include "client/sdk/param_cache.h"

#include <utility>
#include <vector>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "formats/crc32c.h"
#include "formats/params_json.h"
#include "util/file.h"

namespace imucal::sdk {
namespace {

// Reads "KEY VALUE\n" from the front of `rest`.
absl::StatusOr<std::string> TakeField(std::string_view* rest, std::string_view key,
                                      const std::string& path) {
  const size_t eol = rest->find('\n');
  if (eol == std::string_view::npos)
    return absl::DataLossError(
        absl::StrCat(path, ": truncated header (no '", std::string(key), "' line)"));
  std::string_view line = rest->substr(0, eol);
  rest->remove_prefix(eol + 1);
  const std::string prefix = absl::StrCat(std::string(key), " ");
  if (line.substr(0, prefix.size()) != prefix)
    return absl::DataLossError(absl::StrCat(path, ": malformed header: expected '",
                                            std::string(key), " ...', found '",
                                            std::string(line.substr(0, 40)), "'"));
  return std::string(line.substr(prefix.size()));
}

}  // namespace

absl::StatusOr<LoadedParams> ParseStoredParams(StoredParams stored) {
  const uint32_t actual = formats::Crc32c(stored.json);
  if (actual != stored.crc32c) {
    return absl::DataLossError(absl::StrFormat(
        "parameter set %s v%d: checksum mismatch (crc32c %08x stated, %08x computed)",
        stored.device_id, stored.version, stored.crc32c, actual));
  }
  absl::StatusOr<core::ParamSet> params = formats::ParamSetFromJson(stored.json);
  if (!params.ok()) return params.status();
  if (params->version != 0 && params->version != stored.version) {
    return absl::DataLossError(absl::StrFormat("parameter set: JSON version %d but header says %d",
                                               params->version, stored.version));
  }
  if (!params->device.empty() && params->device != stored.device_id) {
    return absl::DataLossError(absl::StrFormat(
        "parameter set: JSON device '%s' but header says '%s'", params->device, stored.device_id));
  }
  return LoadedParams{std::move(stored), *std::move(params)};
}

absl::Status SaveParamCache(const std::string& path, const StoredParams& params) {
  if (formats::Crc32c(params.json) != params.crc32c)
    return absl::InvalidArgumentError("parameter set: crc32c does not match its JSON");
  if (params.device_id.find('\n') != std::string::npos)
    return absl::InvalidArgumentError("parameter set: device id contains a line break");
  const std::string text = absl::StrFormat(
      "%s\ndevice %s\nversion %d\ncrc32c %08x\nlength %d\n\n%s", kParamCacheFormat,
      params.device_id, params.version, params.crc32c, params.json.size(), params.json);
  return WriteFileDurably(path, text);
}

absl::StatusOr<LoadedParams> LoadParamCache(const std::string& path) {
  absl::StatusOr<std::string> text = ReadFileBytes(path);
  if (!text.ok()) return text.status();
  std::string_view rest = *text;
  const size_t eol = rest.find('\n');
  const std::string_view magic = rest.substr(0, eol);
  if (magic.substr(0, 19) != "imucal-param-cache ")
    return absl::DataLossError(absl::StrCat(path, ": not an imucal parameter cache"));
  if (magic != kParamCacheFormat) {
    return absl::DataLossError(
        absl::StrCat(path, ": cache format '", std::string(magic.substr(0, 40)),
                     "' is not supported (this SDK reads '", std::string(kParamCacheFormat), "')"));
  }
  rest.remove_prefix(eol + 1);
  StoredParams stored;
  absl::StatusOr<std::string> device = TakeField(&rest, "device", path);
  if (!device.ok()) return device.status();
  stored.device_id = *device;
  absl::StatusOr<std::string> version = TakeField(&rest, "version", path);
  if (!version.ok()) return version.status();
  if (!absl::SimpleAtoi(*version, &stored.version))
    return absl::DataLossError(absl::StrCat(path, ": malformed version '", *version, "'"));
  absl::StatusOr<std::string> crc = TakeField(&rest, "crc32c", path);
  if (!crc.ok()) return crc.status();
  if (crc->size() != 8 || !absl::SimpleHexAtoi(*crc, &stored.crc32c))
    return absl::DataLossError(absl::StrCat(path, ": malformed crc32c '", *crc, "'"));
  absl::StatusOr<std::string> length = TakeField(&rest, "length", path);
  if (!length.ok()) return length.status();
  size_t bytes = 0;
  if (!absl::SimpleAtoi(*length, &bytes))
    return absl::DataLossError(absl::StrCat(path, ": malformed length '", *length, "'"));
  if (rest.empty() || rest.front() != '\n')
    return absl::DataLossError(absl::StrCat(path, ": malformed header (no blank line)"));
  rest.remove_prefix(1);
  if (rest.size() != bytes) {
    return absl::DataLossError(absl::StrFormat("%s: %s (%d bytes of JSON, header says %d)", path,
                                               rest.size() < bytes ? "truncated" : "trailing data",
                                               rest.size(), bytes));
  }
  stored.json = std::string(rest);
  absl::StatusOr<LoadedParams> loaded = ParseStoredParams(std::move(stored));
  if (!loaded.ok()) {
    return absl::DataLossError(absl::StrCat(path, ": ", loaded.status().message()));
  }
  return loaded;
}

}  // namespace imucal::sdk
