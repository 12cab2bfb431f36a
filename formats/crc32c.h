// CRC-32C (Castagnoli, reflected polynomial 0x82F63B78, init and final xor 0xFFFFFFFF), the
// checksum ParameterSet.crc32c carries for its `json`. Its two ends, the server that computes it
// (server/convert.h) and the SDK's cache that checks it (client/sdk/param_cache.h), call this one
// function, so they cannot drift apart. The system absl predates absl/crc, hence this
// table-driven version; check value: Crc32c("123456789") == 0xE3069283.
#ifndef IMUCAL_FORMATS_CRC32C_H_
#define IMUCAL_FORMATS_CRC32C_H_

#include <cstdint>
#include <string_view>

namespace imucal::formats {

uint32_t Crc32c(std::string_view data);

}  // namespace imucal::formats

#endif  // IMUCAL_FORMATS_CRC32C_H_
