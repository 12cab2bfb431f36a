#include "server/session_hub.h"

#include <optional>
#include <utility>

#include "absl/strings/str_format.h"
#include "absl/time/clock.h"
#include "core/capture.h"
#include "storage/sample_codec.h"
#include "util/str_util.h"

namespace imucal::server {

v1::SessionEvent Stamped() {
  v1::SessionEvent e;
  ToTimestamp(absl::Now(), e.mutable_time());
  return e;
}

core::OnlineSegmenterOptions SegmenterOptionsFor(const storage::Device& device,
                                                 v1::Protocol protocol) {
  core::OnlineSegmenterOptions opt;
  opt.rate_hz = device.nominal_rate_hz;
  switch (protocol) {
    case v1::PROTOCOL_SIX_FACE:
      opt.protocol = core::GuidedProtocol::kSixFace;
      break;
    case v1::PROTOCOL_POSITIONS:
      opt.protocol = core::GuidedProtocol::kPositions;
      break;
    case v1::PROTOCOL_FREE:
      opt.protocol = core::GuidedProtocol::kFree;
      break;
    default:  // unspecified, Ferraris (its turns are moves, not poses): no target
      opt.protocol = core::GuidedProtocol::kAny;
      break;
  }
  if (auto unit = core::ParseAccelUnit(device.accel_unit); unit.ok()) opt.accel_unit = *unit;
  if (auto unit = core::ParseGyroUnit(device.gyro_unit); unit.ok()) opt.gyro_unit = *unit;
  return opt;
}

namespace {

// Appends the segmenter's `fresh` events to `events`, each accepted pose followed by the pair
// verdicts it completes; a failed pair replaces the guidance that follows it with its re-do.
void AddSegmenterEvents(LiveSession& session, std::vector<core::SegmenterEvent>& fresh,
                        std::vector<LiveEvent>* events) {
  std::optional<core::NextPoseUpdate> redo;
  for (core::SegmenterEvent& e : fresh) {
    if (e.kind == core::SegmenterEvent::Kind::kNextPose && redo) {
      e.next_pose = *std::exchange(redo, std::nullopt);
    }
    const bool accepted_pose = e.kind == core::SegmenterEvent::Kind::kPose && e.pose.accepted;
    std::vector<core::PairCheck> verdicts;
    if (accepted_pose) verdicts = session.pairs->OnPoseAccepted(e.pose);
    const int pose_index = e.pose.index;
    const bool is_pose = e.kind == core::SegmenterEvent::Kind::kPose;
    const size_t pose_at = events->size();
    events->push_back(LiveEvent{LiveEvent::Kind::kSegmenter, std::move(e), {}, {}});
    for (core::PairCheck& p : verdicts) {
      if (!p.ok && p.pose_b == pose_index && session.segmenter->RedoTurn(p.face)) {
        redo = session.segmenter->CurrentNextPose();
        redo->instruction = Cat(
            "Pair ", p.face, " failed (", p.reason, "). Redo it: place it on ", p.face,
            " again, half a turn about the vertical from its first placement, and keep it still");
      }
      LiveEvent pe;
      pe.kind = LiveEvent::Kind::kPair;
      pe.pair = std::move(p);
      events->push_back(std::move(pe));
    }
    if (is_pose) (*events)[pose_at].progress = SessionHub::ProgressEvent(session);
  }
  fresh.clear();
}

}  // namespace

void Segment(LiveSession& session, const std::vector<storage::ImuSample>& samples,
             std::vector<LiveEvent>* events) {
  std::vector<core::SegmenterEvent> fresh;
  for (const storage::ImuSample& x : samples) {
    const Eigen::Vector3d gyro(x.gyro[0], x.gyro[1], x.gyro[2]);
    session.pairs->AddGyro(x.t_s, gyro);
    session.segmenter->Add(x.t_s, Eigen::Vector3d(x.accel[0], x.accel[1], x.accel[2]), gyro,
                           &fresh);
    if (!fresh.empty()) AddSegmenterEvents(session, fresh, events);
  }
}

void FlushSegment(LiveSession& session, std::vector<LiveEvent>* events) {
  std::vector<core::SegmenterEvent> fresh;
  session.segmenter->Flush(&fresh);
  AddSegmenterEvents(session, fresh, events);
}

void RecordProof(LiveSession& session, int64_t seq, int64_t samples) {
  session.proofs.push_back({seq, samples, session.digest.Sha256()});
  while (session.proofs.size() > LiveSession::kProofHistory) session.proofs.pop_front();
}

const LiveSession::Proof* ProofAfter(const LiveSession& session, int64_t seq) {
  for (const LiveSession::Proof& p : session.proofs)
    if (p.seq == seq) return &p;
  return nullptr;
}

void ToRows(const std::vector<LiveEvent>& events, std::vector<storage::Pose>* poses,
            std::vector<storage::PosePair>* pairs) {
  for (const LiveEvent& e : events) {
    if (e.kind == LiveEvent::Kind::kPair) {
      storage::PosePair p;
      p.pose_a = e.pair.pose_a;
      p.pose_b = e.pair.pose_b;
      p.ok = e.pair.ok;
      p.face = e.pair.face;
      p.rotation_deg = e.pair.rotation_deg;
      p.tilt_deg = e.pair.tilt_deg;
      p.reason = e.pair.reason;
      pairs->push_back(std::move(p));
    } else if (e.segmenter.kind == core::SegmenterEvent::Kind::kPose) {
      const core::PoseUpdate& u = e.segmenter.pose;
      storage::Pose p;
      p.index = u.index;
      p.t_start_s = u.t_start_s;
      p.t_end_s = u.t_end_s;
      p.used = u.accepted;
      p.reason = u.reason;
      p.face = u.face;
      p.detail_json = absl::StrFormat(
          R"({"samples": %d, "accel_mean": [%.9g, %.9g, %.9g], "gyro_mean": [%.9g, %.9g, %.9g]})",
          u.samples, u.accel_mean.x(), u.accel_mean.y(), u.accel_mean.z(), u.gyro_mean.x(),
          u.gyro_mean.y(), u.gyro_mean.z());
      poses->push_back(std::move(p));
    }
  }
}

absl::StatusOr<std::shared_ptr<LiveSession>> SessionHub::Get(std::string_view session_id) {
  std::promise<Loaded> promise;
  std::shared_future<Loaded> pending;  // another caller's load of the same session
  {
    std::lock_guard lock(mu_);
    if (auto it = sessions_.find(session_id); it != sessions_.end()) return it->second;
    if (auto it = loading_.find(session_id); it != loading_.end()) {
      pending = it->second;
    } else {
      loading_.emplace(std::string(session_id), promise.get_future().share());
    }
  }
  if (pending.valid()) return pending.get();
  // Loading decodes every stored batch: outside mu_.
  Loaded loaded = Load(session_id);
  {
    std::lock_guard lock(mu_);
    // Only what needs its live state stays: a closed session is forgotten at once.
    if (loaded.ok() && !(*loaded)->closed) sessions_.emplace(std::string(session_id), *loaded);
    loading_.erase(loading_.find(session_id));
  }
  promise.set_value(loaded);
  return loaded;
}

std::shared_ptr<LiveSession> SessionHub::Find(std::string_view session_id) {
  std::lock_guard lock(mu_);
  auto it = sessions_.find(session_id);
  return it == sessions_.end() ? nullptr : it->second;
}

SessionHub::~SessionHub() {
  std::lock_guard lock(mu_);
  for (auto& [id, session] : sessions_) {
    std::scoped_lock session_lock(session->mu, session->watchers_mu);
  }
}

size_t SessionHub::LiveSessions() {
  std::lock_guard lock(mu_);
  return sessions_.size();
}

int SessionHub::PeekPosesAccepted(std::string_view session_id) {
  std::shared_ptr<LiveSession> s = Find(session_id);
  if (s == nullptr) return -1;
  std::lock_guard lock(s->mu);
  return s->segmenter->poses_accepted();
}

absl::Status SessionHub::Replay(LiveSession& live, const std::vector<storage::SampleBatch>& batches,
                                std::vector<LiveEvent>* events) {
  std::vector<storage::ImuSample> samples;
  // Only the last proofs are kept: hashing every batch of a long session would be wasted.
  const size_t first_proof = batches.size() > LiveSession::kProofHistory
                                 ? batches.size() - LiveSession::kProofHistory
                                 : 0;
  for (size_t k = 0; k < batches.size(); ++k) {
    const storage::SampleBatch& b = batches[k];
    samples.clear();
    if (absl::Status s = storage::DecodeSamplesInto(b.payload, &samples); !s.ok()) return s;
    live.digest.AddRecords(std::string_view(b.payload).substr(storage::kSampleHeaderBytes));
    Segment(live, samples, events);
    if (!samples.empty()) live.last_t_s = samples.back().t_s;
    live.samples += static_cast<int64_t>(samples.size());
    live.last_acked_seq = b.seq;
    if (k >= first_proof) RecordProof(live, b.seq, live.samples);
  }
  return absl::OkStatus();
}

absl::StatusOr<std::vector<v1::SessionEvent>> SessionHub::CatchUpLocked(LiveSession& live) {
  absl::StatusOr<std::vector<storage::SampleBatch>> later =
      store_->ReadBatches(live.id, live.last_acked_seq);
  if (!later.ok()) return later.status();
  if (later->empty()) return std::vector<v1::SessionEvent>();
  std::vector<LiveEvent> events;
  if (absl::Status s = Replay(live, *later, &events); !s.ok()) return s;
  return ToEvents(events);
}

absl::StatusOr<std::shared_ptr<LiveSession>> SessionHub::Load(std::string_view session_id) {
  absl::StatusOr<storage::Session> session = store_->GetSession(session_id);
  if (!session.ok()) return session.status();
  absl::StatusOr<storage::Device> device = store_->GetDevice(session->device_id);
  if (!device.ok()) return device.status();
  auto live = std::make_shared<LiveSession>();
  live->id = session->id;
  live->device = *device;
  live->protocol = ParseProtocol(session->protocol);
  live->gravity_m_s2 = session->gravity_m_s2;
  live->source = session->source;
  live->segmenter =
      std::make_unique<core::OnlineSegmenter>(SegmenterOptionsFor(*device, live->protocol));
  live->pairs = std::make_unique<PairTracker>(live->protocol == v1::PROTOCOL_SIX_FACE,
                                              device->accel_unit, device->gyro_unit);
  absl::StatusOr<std::vector<storage::SampleBatch>> batches = store_->ReadBatches(session_id);
  if (!batches.ok()) return batches.status();
  std::vector<LiveEvent> events;
  if (absl::Status s = Replay(*live, *batches, &events); !s.ok()) return s;
  std::vector<storage::Pose> poses;
  std::vector<storage::PosePair> pairs;
  ToRows(events, &poses, &pairs);
  // A server killed between a batch's commit and its poses' leaves them missing: the replay
  // found them again (the segmentation is deterministic); store what is not there yet.
  absl::StatusOr<std::vector<storage::Pose>> stored = store_->ListPoses(session_id);
  if (!stored.ok()) return stored.status();
  absl::StatusOr<std::vector<storage::PosePair>> stored_pairs = store_->ListPairs(session_id);
  if (!stored_pairs.ok()) return stored_pairs.status();
  if (stored->size() < poses.size() || stored_pairs->size() < pairs.size()) {
    if (absl::Status s = store_->SavePoses(session_id, poses, pairs); !s.ok()) return s;
  }
  live->closed = session->state != storage::SessionState::kOpen &&
                 session->state != storage::SessionState::kSolving;
  return live;
}

void SessionHub::Publish(LiveSession& session, const v1::SessionEvent& event) {
  std::lock_guard lock(session.watchers_mu);
  for (Watcher* w : session.watchers) w->Push(event);
}

void SessionHub::AddWatcher(LiveSession& session, Watcher* watcher) {
  std::lock_guard lock(session.watchers_mu);
  if (session.closed) {
    watcher->Close();
    return;
  }
  session.watchers.push_back(watcher);
}

void SessionHub::RemoveWatcher(LiveSession& session, Watcher* watcher) {
  std::lock_guard lock(session.watchers_mu);
  std::erase(session.watchers, watcher);
}

std::vector<std::shared_ptr<LiveSession>> SessionHub::WatchedSessions() {
  std::vector<std::shared_ptr<LiveSession>> all;
  {
    std::lock_guard lock(mu_);
    for (const auto& [id, live] : sessions_) all.push_back(live);
  }
  std::erase_if(all, [](const std::shared_ptr<LiveSession>& live) { return !Watched(*live); });
  return all;
}

bool SessionHub::Watched(LiveSession& session) {
  std::lock_guard lock(session.watchers_mu);
  return !session.watchers.empty();
}

void SessionHub::CloseSession(LiveSession& session) {
  // Forgotten before the watchers' streams end: a client that sees its watch end finds the
  // session no longer live (a read then answers from storage, which the caller has already
  // updated), never a closed session still held in memory.
  {
    std::lock_guard lock(mu_);
    sessions_.erase(session.id);
  }
  std::lock_guard lock(session.watchers_mu);
  session.closed = true;
  for (Watcher* w : session.watchers) w->Close();
  session.watchers.clear();
}

void SessionHub::Reopen(const std::shared_ptr<LiveSession>& session) {
  {
    std::lock_guard lock(mu_);
    sessions_.emplace(session->id, session);
  }
  std::lock_guard lock(session->watchers_mu);
  session->closed = false;
}

v1::SessionEvent SessionHub::NextPoseEvent(const core::NextPoseUpdate& next) {
  v1::SessionEvent e = Stamped();
  v1::NextPose* n = e.mutable_next_pose();
  n->set_instruction(next.instruction);
  n->set_face(next.face);
  n->set_turn_half(next.turn_half);
  return e;
}

v1::SessionEvent SessionHub::ProgressEvent(const LiveSession& session) {
  v1::SessionEvent e = Stamped();
  v1::Progress* p = e.mutable_progress();
  const core::GuideProgress progress = session.segmenter->Progress();
  p->set_poses_accepted(progress.poses_accepted);
  p->set_poses_wanted(progress.poses_wanted);
  for (const std::string& f : progress.done) p->add_faces_done(f);
  for (const std::string& f : progress.pending) p->add_faces_pending(f);
  p->set_coverage(progress.coverage);
  return e;
}

v1::PairVerdict SessionHub::ToProto(const core::PairCheck& pair) {
  v1::PairVerdict v;
  v.set_pose_a(pair.pose_a);
  v.set_pose_b(pair.pose_b);
  v.set_ok(pair.ok);
  v.set_face(pair.face);
  v.set_rotation_deg(pair.rotation_deg);
  v.set_tilt_deg(pair.tilt_deg);
  v.set_reason(pair.reason);
  return v;
}

std::vector<v1::SessionEvent> SessionHub::ToEvents(const std::vector<LiveEvent>& events) {
  std::vector<v1::SessionEvent> out;
  for (const LiveEvent& le : events) {
    if (le.kind == LiveEvent::Kind::kPair) {
      v1::SessionEvent e = Stamped();
      *e.mutable_pair() = ToProto(le.pair);
      out.push_back(std::move(e));
      continue;
    }
    const core::SegmenterEvent& se = le.segmenter;
    switch (se.kind) {
      case core::SegmenterEvent::Kind::kStillness: {
        v1::SessionEvent e = Stamped();
        v1::Stillness* s = e.mutable_stillness();
        s->set_still(se.stillness.still);
        s->set_still_for_s(se.stillness.still_for_s);
        s->set_needed_s(se.stillness.needed_s);
        s->set_motion_ratio(se.stillness.motion_ratio);
        out.push_back(std::move(e));
        break;
      }
      case core::SegmenterEvent::Kind::kPose: {
        v1::SessionEvent e = Stamped();
        v1::PoseEvent* p = e.mutable_pose();
        p->set_index(se.pose.index);
        p->set_accepted(se.pose.accepted);
        p->set_reason(se.pose.reason);
        p->set_face(se.pose.face);
        p->set_t_start_s(se.pose.t_start_s);
        p->set_t_end_s(se.pose.t_end_s);
        out.push_back(std::move(e));
        out.push_back(le.progress);
        break;
      }
      case core::SegmenterEvent::Kind::kNextPose:
        out.push_back(NextPoseEvent(se.next_pose));
        break;
    }
  }
  return out;
}

}  // namespace imucal::server
