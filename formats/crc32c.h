// CRC-32C (Castagnoli, reflected polynomial 0x82F63B78, init and final xor 0xFFFFFFFF), the
// checksum ParameterSet.crc32c carries for its `json`. The system absl predates absl/crc, so
// the SDK has its own table-driven version; check value: Crc32c("123456789") == 0xE3069283.
#ifndef IMUCAL_FORMATS_CRC32C_H_
#define IMUCAL_FORMATS_CRC32C_H_

#include <cstdint>
#include <string_view>

namespace imucal::formats {

uint32_t Crc32c(std::string_view data);

}  // namespace imucal::formats

#endif  // IMUCAL_FORMATS_CRC32C_H_
