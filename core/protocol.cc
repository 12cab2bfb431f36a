#include "core/protocol.h"

#include <array>
#include <cmath>
#include <limits>

#include "Eigen/Geometry"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "core/so3.h"
#include "util/units.h"

namespace imucal::core {
namespace {

// Rotation angle (deg) and the angle (deg) between its axis and the vertical `up`.
struct Turn {
  double angle_deg = 0;
  double axis_off_vertical_deg = 90;
};
Turn TurnAbout(const Eigen::Vector3d& rotation, const Eigen::Vector3d& up) {
  Turn t;
  const double angle = rotation.norm();
  t.angle_deg = angle * kRadToDeg;
  if (angle > 1e-9) {
    const double c = std::abs(rotation.normalized().dot(up.normalized()));
    t.axis_off_vertical_deg = std::acos(std::min(1.0, c)) * kRadToDeg;
  }
  return t;
}

Eigen::Vector3d Compose(const Eigen::Vector3d& r1, const Eigen::Vector3d& r2) {
  auto exp = [](const Eigen::Vector3d& r) {
    const double a = r.norm();
    return a > 0 ? Eigen::Matrix3d(Eigen::AngleAxisd(a, r / a)) : Eigen::Matrix3d::Identity();
  };
  const Eigen::AngleAxisd aa(exp(r1) * exp(r2));
  return aa.angle() * aa.axis();
}

// Verifies one candidate pair; fills everything but the indices.
PairCheck VerifyPair(const FacePose& a, const FacePose& b, const Eigen::Vector3d& rotation,
                     double tolerance_deg) {
  PairCheck p;
  const Face fa = ClassifyFace(a.up), fb = ClassifyFace(b.up);
  p.face = fa.Label();
  p.tilt_deg = 0.5 * AngleBetweenDeg(a.up, b.up);
  const Turn turn = TurnAbout(rotation, a.up);
  p.rotation_deg = turn.angle_deg;
  Eigen::Vector3d axis = Eigen::Vector3d::Zero();
  axis(fa.axis) = fa.sign;
  // Mirrored horizontal components: the pair's mean up is the face axis up to the (small)
  // installation misalignment; a pair that is not mirrored leaves the floor tilt in it.
  const double misalignment_deg = AngleBetweenDeg((a.up + b.up).normalized(), axis);
  if (!(fa == fb)) {
    p.reason = absl::StrFormat("wrong face: %s was up, then %s; turn about the vertical only",
                               fa.Label(), fb.Label());
  } else if (!b.rotation_known) {
    p.turn_checked = false;
    p.ok = misalignment_deg <= 2 * kFaceToleranceDeg / 3;
    p.rotation_deg = std::numeric_limits<double>::quiet_NaN();
    if (!p.ok) {
      p.reason = absl::StrFormat(
          "horizontal components do not mirror (mean %.1f degrees off the face axis)",
          misalignment_deg);
    }
  } else if (turn.angle_deg < 20) {
    p.reason = absl::StrFormat(
        "not turned: only %.0f degrees between the placements; turn it half a turn about the "
        "vertical",
        turn.angle_deg);
  } else if (std::abs(turn.angle_deg - 180) > tolerance_deg) {
    p.reason = absl::StrFormat(
        "turned %.0f degrees instead of 180; place it again, half a turn from the first placement",
        turn.angle_deg);
  } else if (turn.axis_off_vertical_deg > 30) {
    p.reason = absl::StrFormat(
        "the turn was about an axis %.0f degrees from vertical; keep the face on the floor",
        turn.axis_off_vertical_deg);
  } else if (misalignment_deg > 2 * kFaceToleranceDeg / 3) {
    p.reason =
        absl::StrFormat("horizontal components do not mirror (mean %.1f degrees off the face axis)",
                        misalignment_deg);
  } else {
    p.ok = true;
  }
  return p;
}

}  // namespace

std::string_view ProtocolKindName(ProtocolKind kind) {
  switch (kind) {
    case ProtocolKind::kAuto:
      return "auto";
    case ProtocolKind::kSixFace:
      return "six-face";
    case ProtocolKind::kPositions:
      return "positions";
    case ProtocolKind::kFree:
      return "free";
    case ProtocolKind::kFerraris:
      return "ferraris";
    case ProtocolKind::kFaces:
      return "faces";
  }
  return "auto";
}

absl::StatusOr<ProtocolKind> ParseProtocolKind(std::string_view name) {
  if (name == "auto") return ProtocolKind::kAuto;
  if (name == "six-face") return ProtocolKind::kSixFace;
  if (name == "positions" || name == "positions24" || name == "positions36")
    return ProtocolKind::kPositions;
  if (name == "free") return ProtocolKind::kFree;
  if (name == "ferraris") return ProtocolKind::kFerraris;
  if (name == "faces") return ProtocolKind::kFaces;
  return absl::InvalidArgumentError(absl::StrFormat(
      "--protocol: '%s' is not one of auto, six-face, positions, positions24, positions36, free, "
      "ferraris, faces",
      name));
}

std::string Face::Label() const {
  return absl::StrFormat("%c%c", "XYZ"[axis], sign > 0 ? '+' : '-');
}

Eigen::Vector3d Face::Reference(double g) const {
  Eigen::Vector3d ref = Eigen::Vector3d::Zero();
  ref(axis) = sign * g;
  return ref;
}

Face ClassifyFace(const Eigen::Vector3d& up_body) {
  Face f;
  const Eigen::Vector3d u = up_body.normalized();
  u.cwiseAbs().maxCoeff(&f.axis);
  f.sign = u(f.axis) >= 0 ? 1 : -1;
  f.off_axis_deg = std::acos(std::min(1.0, std::abs(u(f.axis)))) * kRadToDeg;
  return f;
}

std::array<std::vector<int>, 6> FacePlacements(const std::vector<Eigen::Vector3d>& ups) {
  std::array<std::vector<int>, 6> out;
  for (size_t i = 0; i < ups.size(); ++i) {
    const Face f = ClassifyFace(ups[i]);
    if (f.off_axis_deg <= kFaceToleranceDeg)
      out[static_cast<size_t>(2 * f.axis + (f.sign > 0 ? 0 : 1))].push_back(static_cast<int>(i));
  }
  return out;
}

bool CoversSixFaces(const std::vector<Eigen::Vector3d>& ups) {
  for (const auto& p : FacePlacements(ups))
    if (p.empty()) return false;
  return true;
}

ProtocolKind DetectProtocol(const std::vector<Eigen::Vector3d>& ups) {
  if (ups.empty()) return ProtocolKind::kFree;
  // Six-face: every face placed twice in a row (the 180-degree pair); extra poses may follow.
  // A positions scheme also visits every face, but never the same face twice in a row.
  std::array<bool, 6> consecutive{};
  for (size_t i = 0; i + 1 < ups.size(); ++i) {
    const Face a = ClassifyFace(ups[i]), b = ClassifyFace(ups[i + 1]);
    if (a == b && a.off_axis_deg <= kFaceToleranceDeg && b.off_axis_deg <= kFaceToleranceDeg)
      consecutive[static_cast<size_t>(2 * a.axis + (a.sign > 0 ? 0 : 1))] = true;
  }
  bool all_paired = true;
  for (bool c : consecutive) all_paired &= c;
  if (all_paired) return ProtocolKind::kSixFace;

  // seeds/002: the positions between faces (45 or 30 degrees) keep their group's rotation axis
  // horizontal. Hand-held poses off the faces rarely do.
  std::array<int, 3> horizontal{};
  int off_face = 0, off_face_horizontal = 0;
  for (const auto& up : ups) {
    if (ClassifyFace(up).off_axis_deg <= kFaceToleranceDeg) continue;
    ++off_face;
    const Eigen::Vector3d u = up.normalized();
    bool any = false;
    for (int j = 0; j < 3; ++j) {
      const bool h = std::abs(u(j)) < 0.087;  // within 5 degrees of horizontal
      horizontal[static_cast<size_t>(j)] += h;
      any |= h;
    }
    off_face_horizontal += any;
  }
  if (3 * off_face >= static_cast<int>(ups.size()) && 5 * off_face_horizontal >= 4 * off_face &&
      horizontal[0] >= 2 && horizontal[1] >= 2 && horizontal[2] >= 2)
    return ProtocolKind::kPositions;
  return ProtocolKind::kFree;
}

SixFaceCheck CheckSixFacePairs(const std::vector<FacePose>& poses, double turn_tolerance_deg) {
  SixFaceCheck out;
  std::array<bool, 6> verified{};
  std::array<std::vector<int>, 6> placements;
  auto slot = [](const Face& f) { return static_cast<size_t>(2 * f.axis + (f.sign > 0 ? 0 : 1)); };
  for (const FacePose& p : poses) {
    const Face f = ClassifyFace(p.up);
    if (f.off_axis_deg <= kFaceToleranceDeg) placements[slot(f)].push_back(p.index);
  }
  for (size_t i = 0; i + 1 < poses.size();) {
    const Face fa = ClassifyFace(poses[i].up);
    const Face fb = ClassifyFace(poses[i + 1].up);
    // Once a face has its verified pair, further placements of it are extra poses, not pairs.
    if (fa.off_axis_deg > kFaceToleranceDeg || !(fa == fb) || verified[slot(fa)]) {
      ++i;
      continue;
    }
    PairCheck check =
        VerifyPair(poses[i], poses[i + 1], poses[i + 1].rotation_from_previous, turn_tolerance_deg);
    check.pose_a = poses[i].index;
    check.pose_b = poses[i + 1].index;
    if (!check.ok && i + 2 < poses.size() && ClassifyFace(poses[i + 2].up) == fa) {
      // A re-done placement: the third placement may be the proper half turn from the first.
      out.pairs.push_back(check);
      PairCheck redo = VerifyPair(
          poses[i], poses[i + 2],
          Compose(poses[i + 1].rotation_from_previous, poses[i + 2].rotation_from_previous),
          turn_tolerance_deg);
      redo.pose_a = poses[i].index;
      redo.pose_b = poses[i + 2].index;
      if (redo.ok) {
        verified[slot(fa)] = true;
        out.pairs.push_back(redo);
        i += 3;
        continue;
      }
      ++i;
      continue;
    }
    if (check.ok) verified[slot(fa)] = true;
    out.pairs.push_back(check);
    i += check.ok ? 2 : 1;
  }
  for (size_t s = 0; s < 6; ++s) {
    if (verified[s]) continue;
    Face f;
    f.axis = static_cast<int>(s / 2);
    f.sign = s % 2 == 0 ? 1 : -1;
    out.missing.push_back(
        placements[s].empty()
            ? absl::StrFormat("face %s: never placed", f.Label())
            : absl::StrFormat("face %s: no verified 180-degree pair (placements at poses %s)",
                              f.Label(), absl::StrJoin(placements[s], ", ")));
  }
  return out;
}

Eigen::Vector3d PairTurnAxis(const Eigen::Vector3d& up_a, const Eigen::Vector3d& up_b,
                             const Eigen::Vector3d& turn_rad) {
  const Eigen::Vector3d sum = up_a + up_b, diff = up_a - up_b;
  const Eigen::Vector3d mean = sum.normalized();
  const double turn = turn_rad.norm();
  if (diff.norm() < 1e-12 || sum.norm() < 1e-12 || turn < 1e-6) return mean;
  // Orthonormal frame of the bisector geometry: m (the mean), e (from up_b to up_a), d = m x e.
  // up_a = a m + b e and up_b = a m - b e; the axis is cos(phi) m +- sin(phi) d.
  const Eigen::Vector3d e = diff.normalized(), d = mean.cross(e);
  const double a = up_a.dot(mean), b = up_a.dot(e);
  const double sin_phi = b / a / std::tan(0.5 * turn);
  if (!std::isfinite(sin_phi) || std::abs(sin_phi) > std::sin(0.1)) return mean;
  const double cos_phi = std::sqrt(1.0 - sin_phi * sin_phi);
  // The turn's sense along the axis, from the gyro; the candidate that turns up_a onto up_b.
  const double sense = turn_rad.dot(mean) >= 0 ? 1.0 : -1.0;
  Eigen::Vector3d best = mean;
  double best_miss = std::numeric_limits<double>::infinity();
  for (const double side : {1.0, -1.0}) {
    const Eigen::Vector3d axis = cos_phi * mean + side * sin_phi * d;
    const Eigen::Vector3d turned = Eigen::AngleAxisd(-sense * turn, axis) * up_a;
    const double miss = (turned - up_b).norm();
    if (miss < best_miss) best_miss = miss, best = axis;
  }
  return best;
}

}  // namespace imucal::core
