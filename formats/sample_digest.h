// What proves that a stream continues the capture a session already holds: SHA-256 over the
// samples in order, each as the little-endian IEEE-754 doubles t_s, accel x, y, z, gyro x, y, z
// and, when its batch carries temperature, temp_c (56 or 64 bytes a sample). These are the
// record bytes the server stores for a batch (storage/sample_codec.h, after the 6-byte header),
// so the server keeps the digest of each open session's samples as they arrive, and a client
// computes the same over the start of its capture (SampleBatch.resume_sha256, imucal.proto).
// Values are kept exactly as sent, so the same capture gives the same bytes on both sides.
#ifndef IMUCAL_FORMATS_SAMPLE_DIGEST_H_
#define IMUCAL_FORMATS_SAMPLE_DIGEST_H_

#include <cstdint>
#include <memory>
#include <string>
#include <string_view>

namespace imucal::formats {

class SampleDigest {
 public:
  static constexpr size_t kBytes = 32;  // SHA-256

  SampleDigest();
  ~SampleDigest();
  // Copies carry the running state: a copy can go on from where the original stood.
  SampleDigest(const SampleDigest& other);
  SampleDigest& operator=(const SampleDigest& other);

  // One sample; `temp_c` null when its batch carries no temperature.
  void AddSample(double t_s, const double* accel3, const double* gyro3, const double* temp_c);
  // Stored records as they are (a payload after its header).
  void AddRecords(std::string_view records);
  // The digest of everything added so far (32 raw bytes); adding may go on after.
  std::string Sha256() const;

 private:
  struct State;
  std::unique_ptr<State> state_;
};

// Lowercase hex of `bytes`, at most `max_chars` of it (for messages).
std::string HexPrefix(std::string_view bytes, size_t max_chars = 64);

}  // namespace imucal::formats

#endif  // IMUCAL_FORMATS_SAMPLE_DIGEST_H_
