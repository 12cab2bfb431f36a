// For tests that stream through the generated stubs: a stream that starts after batch 1 of a
// session holding samples must prove it continues the stored capture (SampleBatch.
// resume_sha256, formats/sample_digest.h). ResumeProofs remembers the batches a test has had
// acknowledged and fills in that proof, as a client that keeps its capture would; a session
// whose batches went another way (a raw stream of the test's own) is proven by the digest the
// server reports, when the stream resumes right after its last batch. Tests of the proof itself
// set resume_sha256 themselves and stream the batches as they are.
#ifndef IMUCAL_TESTS_SERVER_RESUME_PROOFS_H_
#define IMUCAL_TESTS_SERVER_RESUME_PROOFS_H_

#include <chrono>
#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include "formats/sample_digest.h"
#include "grpcpp/grpcpp.h"
#include "imucal/v1/imucal.grpc.pb.h"

namespace imucal::testing_util {

// The SHA-256 of `batches`' samples in order, as a continuing stream sends it.
inline std::string DigestOf(const std::vector<v1::SampleBatch>& batches) {
  formats::SampleDigest digest;
  for (const v1::SampleBatch& b : batches) {
    for (int i = 0; i < b.t_s_size(); ++i) {
      const double temp = b.temp_c_size() > 0 ? b.temp_c(i) : 0.0;
      digest.AddSample(b.t_s(i), b.accel().data() + 3 * i, b.gyro().data() + 3 * i,
                       b.temp_c_size() > 0 ? &temp : nullptr);
    }
  }
  return digest.Sha256();
}

class ResumeProofs {
 public:
  // `batches` were sent on one stream (the first names the session) and `acks` came back.
  void Acked(const std::vector<v1::SampleBatch>& batches, const std::vector<v1::SampleAck>& acks) {
    if (batches.empty() || acks.empty()) return;
    const int64_t last = acks.back().last_acked_seq();
    std::map<int64_t, v1::SampleBatch>& sent = sent_[batches[0].session_id()];
    for (const v1::SampleBatch& b : batches)
      if (b.seq() <= last && !sent.contains(b.seq())) sent[b.seq()] = b;
  }

  // Gives batches[0] the proof of batches 1..seq-1 when it starts after batch 1 and has none.
  void Prove(std::vector<v1::SampleBatch>* batches, v1::SessionService::Stub* stub) {
    if (batches->empty()) return;
    v1::SampleBatch& first = (*batches)[0];
    if (first.seq() <= 1 || !first.resume_sha256().empty() || first.session_id().empty()) return;
    const std::map<int64_t, v1::SampleBatch>& sent = sent_[first.session_id()];
    std::vector<v1::SampleBatch> before;
    for (int64_t seq = 1; seq < first.seq(); ++seq) {
      auto it = sent.find(seq);
      if (it == sent.end()) break;
      before.push_back(it->second);
    }
    if (static_cast<int64_t>(before.size()) == first.seq() - 1) {
      first.set_resume_sha256(DigestOf(before));
      return;
    }
    grpc::ClientContext context;
    context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(20));
    v1::GetSessionRequest req;
    req.set_session_id(first.session_id());
    v1::Session session;
    if (stub->GetSession(&context, req, &session).ok() &&
        session.last_acked_seq() == first.seq() - 1)
      first.set_resume_sha256(session.samples_sha256());
  }

 private:
  std::map<std::string, std::map<int64_t, v1::SampleBatch>> sent_;  // by session, by seq
};

}  // namespace imucal::testing_util

#endif  // IMUCAL_TESTS_SERVER_RESUME_PROOFS_H_
