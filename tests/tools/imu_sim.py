"""A calibration capture simulated from first principles, for the independent capture writers.

Shared by write_rosbag2.py, write_euroc.py and write_columns.py (standard library only, nothing
from imucal). The sensor reads the inverse of imucal's documented model with no misalignment
(README "The model and its conventions"):
    y = scale * (u - bias)  =>  u = y / scale + bias + white noise
per axis, for the specific force (m/s^2) and the angular rate (rad/s). Every rotation is about
one body axis with a rate profile sampled at mid-sample, so the gyroscope reading of a move
integrates exactly to the rotation between its two poses, and each pose's orientation is exact
(no integration drift).

Protocols (--protocol):
  six-face (default)  the body is held on each face twice, the second time turned 180 degrees
      about the vertical, with 90-degree tilts about one body axis in between; the table is
      tilted a little (a pair's two up directions differ) and a hand's 180-degree turn is a few
      degrees off. Four extra poses follow the pairs (EXTRA_TILTS).
  faces-once          the hobbyist's capture: each face held once, in FACE_ORDER, 90-degree
      tilts between them, no 180-degree pair and no extra poses; --floor-tilt-deg still tilts
      the table (its default 0.3 applies; pass 0 for a level floor).
  random              an IMU-TK style capture: a first rest, then --poses stops, each reached by
      a smooth rotation about a random body axis by 30-120 degrees (--move-angle-range-deg).
  rest                a recording for the noise figures: one hold of --first-hold-s, Z+ up,
      nothing else (unless --handling-s).

Classes of capture (each off by default; the default output is the same as before they existed):
  --accel-step / --gyro-step  quantisation: each reading, noise included, becomes
      round(u / step) * step (Python's round: half to even). A step is a number in the sensor's
      SI input unit (m/s^2, rad/s), or a datasheet LSB: "1/16384g" is 9.80665/16384 m/s^2 (the
      LSB of a +-2 g range is defined on standard gravity, not on --gravity), "1/131deg" is
      1/131 deg/s in rad/s. With noise below one step (or --no-noise) an axis reads one value
      through a whole rest. write_columns.py --counts writes round(u / step) as integers.
  --no-noise, or --accel-noise 0 / --gyro-noise 0  noise-free samples (per sensor).
  --turn-profile steady  the 180-degree turns about the vertical (six-face) at a steady rate: a
      trapezoidal rate profile, a linear ramp of --turn-ramp-s (rounded to whole samples, at
      least one) up to the rate, a constant-rate middle, the same ramp down. The middle has a
      whole number of samples and its rate is the largest not above --turn-rate-deg-s that
      makes the turn's angle exact (so a level floor leaves the accelerometer unchanged through
      the turn and the gyroscope constant mid-turn). The default "smooth" profile is
      rate = angle / T * (1 - cos(2 pi t / T)). Tilts between faces keep the smooth profile.
  --noisy-rest POSE  one pose (0-based, in time order) held --noisy-rest-s (default 7 s) with
      more noise than the others while its orientation does not change. --noisy-rest-factor F
      (default 5): its noise's RMS over the hold is F times the others' (an extra independent
      zero-mean noise of RMS sqrt(F^2 - 1) times --accel-noise / --gyro-noise, or F times them
      with --no-noise). --noisy-rest-kind:
        hand      the extra noise is white with an amplitude that comes and goes as a hand
                  presses and relaxes: sqrt(2) |sin(pi t / 1.5 s)| (RMS 1) times its RMS;
        motor     instead, a steady vibration at --motor-hz (default 37 Hz) on each axis,
                  amplitude sqrt(2) F times the noise (RMS F times), random phases;
        settling  the extra noise is white and dies away as exp(-t / (T / 3)) over the hold T
                  (scaled to RMS 1), and an accelerometer offset on every axis decays to zero
                  (the final value): d(t) = d0 exp(-t / tau), d0 = --settle-mg (default 1 mg,
                  of standard gravity), tau chosen so that the offset's mean over the hold is
                  0.1 mg (tau = T * 0.1 / d0 in mg; the exact mean is in the truth).
  --hold-range-s LO,HI  every hold after the first lasts a uniform draw in [LO, HI] s (stops
      too short: e.g. --protocol random --poses 40 --hold-range-s 0.3,0.8).
  --duplicate-face FACE=OTHER  (faces-once) the pose meant for FACE holds OTHER's orientation,
      turned --duplicate-angle-deg (default 0.005) about one of OTHER's horizontal body axes:
      e.g. Z+=Z- leaves no pose with +Z up. The truth keeps the face each pose was meant for.

  --handling-s S  (rest) S seconds of handling inside the rest, starting --handling-at-s after
      its start (default: 40% of the way through): the unit is picked up and put down again,
      four smooth moves of S/4 s about random body axes by 20-60 degrees (its own generator),
      the last one setting it down --handling-tilt-deg (default 2) off its first orientation.
      The truth holds the two holds as poses and the handling's time range.
  --gyro-random-walk K / --accel-random-walk K  a bias random walk on every axis: each sample
      the bias moves by a Gaussian step of K sqrt(dt) (K in rad/s^2/sqrt(Hz) or m/s^3/sqrt(Hz),
      the Allan rate random walk K; its own generator). The walk starts at 0.

  --gyro-bias-shift SIGMA  the gyroscope's bias moves each time the unit is moved: at the middle
      of every move each axis draws a new offset, Gaussian with standard deviation SIGMA rad/s
      (its own generator), added to the true rate from then on (through the next hold). The
      offset of each hold is in the truth (gyro_bias_shift.per_hold_rad_s); the first hold has
      none.

Temperature (off by default; then no sample has one and nothing depends on it):
  --temp-history KIND:ARGS  the temperature T(t), t from the first sample, in degC:
        warmup:T0,T1,TAU  T0 + (T1 - T0) (1 - exp(-t / TAU))
        ramp:T0,T1        linear from T0 at the first sample to T1 at the last
        plateau:T         constant
      Each sample then carries T (write_columns.py writes it in the temp column).
  --gyro-temp-quad AXIS,C,TREF / --accel-temp-quad AXIS,C,TREF  a temperature quadratic with a
      turnover: C (T - TREF)^2 added to the TRUE rate (rad/s) or specific force (m/s^2) on AXIS
      (x, y or z) before the sensor's scale and bias, so the calibrated value carries it with
      coefficient C. Repeatable.

Rate-dependent gyroscope scale (off by default):
  --gyro-rate-scale AXIS,S  a scale that grows with the rate's size: S |w| w (S per rad/s, w the
      TRUE rate on AXIS in rad/s) added to the true rate on AXIS before the sensor's scale and
      bias, so the calibrated rate carries it (the reading's gain is 1 + S |w|). Repeatable. The
      holds show nothing (w = 0 there); only the moves do.

A unit drawn from wide priors (--unit-seed N; off by default): the accelerometer follows imucal's
documented model in full (README "The model and its conventions", frame angles 0): raw
u = y / scale + bias with z_i = y_i + q_i y_i^2 and a = L z, L unit lower-triangular with
t_yx, t_zx, t_zy; so the sensor reads y = (sqrt(1 + 4 q z) - 1) / (2 q) of z = L^-1 a. Drawn
with their own generator from N alone: bias uniform in +-0.3 m/s^2, scale 1 +- 3 %, angles
+-3 mrad, second-order terms log-uniform in 1e-5..3e-4 per m/s^2 with a random sign on every
axis (ordinary for MEMS); gyro bias +-0.02 rad/s, scale 1 +- 3 %. In the truth's
"accel_model" (scale in m/s^2 per input unit, as imucal stores it).

Rests that are hard to tell from turns (off by default):
  --move-profile steady  (random, faces-once) every move at a steady rate (--turn-rate-deg-s,
      ramps of --turn-ramp-s), as a rotation table turns.
  --hand-tremor-deg A  a hand holds the unit: the orientation wobbles by a small rotation
      d(t) (body frame) on each axis, two sinusoids at frequencies drawn in --hand-tremor-hz with
      random phases, RMS A degrees per axis; the gyroscope reads d'(t) on top of the rate and the
      accelerometer the specific force turned by d (to first order: f - d x f). Its own
      generator.
  --slow-turn-every K  (random) after every K-th hold a slow turn about the vertical (the
      table's normal) at a steady rate drawn in --slow-turn-rate-range-deg-s, by the angles of
      --slow-turn-angles-deg in turn (360: back to the same orientation); the next move follows
      at once, with no hold. In the truth's "slow_turns" (time ranges, rate, angle).
  --hold-bursts F  during every hold, bursts of vibration (0.3-1.2 s, every 2-5 s, at
      --motor-hz) of F times the noise RMS on both sensors, as a rotation table's servo holds
      its position: no net rotation, no change of orientation. Its own generator.
  --hold-noise-factors F0,F1,...  hold k's noise is F[k mod n] times the default (moves keep
      the default): with --split pose, per-file noise floors that differ.
  --single-faces FACE,...  (six-face) these faces are held once: no 180-degree turn and no
      second pose for them.

The truth (JSON-ready dict) says what was used. When any option above is not at its default
(or a writer sets args.full_truth), it also holds each pose's time range and each move's time
range, axis, angle and profile; times are the sample times t = k / rate_hz of the capture's
samples (first sample at 0).
"""
import math
import random

STANDARD_GRAVITY_M_S2 = 9.80665
# Faces in visiting order; no face is followed by its opposite, so one 90-degree tilt reaches it.
FACE_ORDER = ["Z+", "X+", "Y+", "Z-", "X-", "Y-"]
# Extra poses after the pairs (the six-face protocol allows them): tilts about body axes, in
# degrees. The twelve face poses alone leave the solve near-degenerate: the tilts between faces
# are about y, z, x, y, z, so gravity sees the gyroscope's x axis turn once (10 direction
# constraints for its 9 unknowns; 180-degree turns about the vertical show gravity nothing), and
# only the table's tilt separates a pair's two up directions, so |a| = g barely sees the
# accelerometer's misalignment. A return to Z+ and three poses off the faces fix both.
EXTRA_TILTS = [((1.0, 0.0, 0.0), 90.0), ((1.0, 0.0, 0.0), 45.0), ((0.0, 1.0, 0.0), 45.0),
               ((1.0, 0.0, 0.0), -90.0)]
PROTOCOLS = ["six-face", "faces-once", "random", "rest"]
NOISY_REST_KINDS = ["hand", "motor", "settling"]
# The settling rest's mean offset from its final value: a sensor still settling has a mean
# steady only to about this much (mg of standard gravity).
SETTLE_MEAN_MG = 0.1
# A hand on the unit presses and relaxes: its noise comes and goes with this half-period (s).
HAND_PRESS_S = 1.5


def _matmul(a, b):
    return [[sum(a[i][k] * b[k][j] for k in range(3)) for j in range(3)] for i in range(3)]


def _transpose_times(r, v):
    """R^T v: a world vector in the body frame."""
    return [sum(r[k][i] * v[k] for k in range(3)) for i in range(3)]


def _transpose(r):
    return [[r[j][i] for j in range(3)] for i in range(3)]


def _axis_angle(axis, angle_rad):
    """Rodrigues: rotation by angle_rad about the unit vector axis."""
    x, y, z = axis
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    t = 1.0 - c
    return [[t * x * x + c, t * x * y - s * z, t * x * z + s * y],
            [t * x * y + s * z, t * y * y + c, t * y * z - s * x],
            [t * x * z - s * y, t * y * z + s * x, t * z * z + c]]


def _rotation_log(m):
    """(unit axis, angle in [0, pi]) of a rotation matrix; near pi from the symmetric part
    (M = c I + s [a]x + (1 - c) a a^T), where the skew part vanishes."""
    c = max(-1.0, min(1.0, (m[0][0] + m[1][1] + m[2][2] - 1.0) / 2.0))
    v = [m[2][1] - m[1][2], m[0][2] - m[2][0], m[1][0] - m[0][1]]  # 2 sin(angle) axis
    s2 = math.sqrt(sum(x * x for x in v))
    angle = math.atan2(s2 / 2.0, c)
    if c < -0.9:
        sq = [max(0.0, (m[i][i] - c) / (1.0 - c)) for i in range(3)]
        i = max(range(3), key=lambda k: sq[k])
        a_i = math.sqrt(sq[i])
        axis = [a_i if j == i else (m[i][j] + m[j][i]) / (2.0 * (1.0 - c) * a_i)
                for j in range(3)]
        if sum(a * b for a, b in zip(axis, v)) < 0:
            axis = [-a for a in axis]
        return axis, angle
    if s2 == 0.0:
        return [1.0, 0.0, 0.0], 0.0
    return [x / s2 for x in v], angle


def _face_label(up_body):
    axis = max(range(3), key=lambda i: abs(up_body[i]))
    return "XYZ"[axis] + ("+" if up_body[axis] > 0 else "-")


def _unit_of_face(label):
    v = [0.0, 0.0, 0.0]
    v["XYZ".index(label[0])] = 1.0 if label[1] == "+" else -1.0
    return v


def parse_step(text, sensor):
    """A quantisation step: a number in the SI input unit (m/s^2 or rad/s), or "A/B" with an
    optional unit suffix: "g" (standard gravity, accel) or "deg" (deg/s, gyro)."""
    unit = 1.0
    body = text.strip()
    if sensor == "accel" and body.endswith("g"):
        body, unit = body[:-1], STANDARD_GRAVITY_M_S2
    elif sensor == "gyro" and body.endswith("deg"):
        body, unit = body[:-3], math.pi / 180.0
    num, _, den = body.partition("/")
    value = float(num) / (float(den) if den else 1.0) * unit
    if not value > 0.0:
        raise ValueError(f"{sensor} step must be positive, got {text!r}")
    return value


def _parse_range(text):
    lo, hi = (float(x) for x in text.split(","))
    if not 0.0 < lo <= hi:
        raise ValueError(f"range LO,HI with 0 < LO <= HI, got {text!r}")
    return lo, hi


def _parse_duplicate(text):
    face, _, other = text.partition("=")
    faces = [f + s for f in "XYZ" for s in "+-"]
    if face not in faces or other not in faces or face == other:
        raise ValueError(f"FACE=OTHER with two different faces like Z+=Z-, got {text!r}")
    return face, other


def _parse_history(text):
    kind, _, rest = text.partition(":")
    values = [float(v) for v in rest.split(",")] if rest else []
    want = {"warmup": 3, "ramp": 2, "plateau": 1}
    if kind not in want or len(values) != want[kind]:
        raise ValueError(f"--temp-history: expected warmup:T0,T1,TAU, ramp:T0,T1 or plateau:T, "
                         f"got {text!r}")
    return (kind, values)


def _parse_quad(text):
    parts = text.split(",")
    if len(parts) != 3 or parts[0] not in ("x", "y", "z"):
        raise ValueError(f"expected AXIS,C,TREF with AXIS x, y or z, got {text!r}")
    return ("xyz".index(parts[0]), float(parts[1]), float(parts[2]))


def _parse_rate_scale(text):
    parts = text.split(",")
    if len(parts) != 2 or parts[0] not in ("x", "y", "z"):
        raise ValueError(f"expected AXIS,S with AXIS x, y or z, got {text!r}")
    return ("xyz".index(parts[0]), float(parts[1]))


def _temperature(history, t, duration):
    kind, v = history
    if kind == "warmup":
        return v[0] + (v[1] - v[0]) * (1.0 - math.exp(-t / v[2]))
    if kind == "ramp":
        return v[0] + (v[1] - v[0]) * (t / duration if duration > 0 else 0.0)
    return v[0]


def add_arguments(parser):
    """The simulation's options, the same for every writer."""
    parser.add_argument("--seed", type=int, default=1, help="noise and turn-error seed")
    parser.add_argument("--rate-hz", type=float, default=100.0)
    parser.add_argument("--first-hold-s", type=float, default=10.0,
                        help="the first pose's hold (the noise is learnt on a long rest)")
    parser.add_argument("--hold-s", type=float, default=3.0)
    parser.add_argument("--move-s", type=float, default=1.5)
    parser.add_argument("--gravity", type=float, default=STANDARD_GRAVITY_M_S2)
    parser.add_argument("--accel-noise", type=float, default=0.02, help="m/s^2 per sample")
    parser.add_argument("--gyro-noise", type=float, default=0.004, help="rad/s per sample")
    parser.add_argument("--turn-error-deg", type=float, default=3.0,
                        help="std dev of the 180-degree turn's error (a hand turns the box)")
    parser.add_argument("--no-extra-poses", dest="extra_poses", action="store_false",
                        help="end on the sixth face's pair (12 poses, not 16)")
    parser.add_argument("--floor-tilt-deg", type=float, default=0.3,
                        help="the table's tilt: gravity leans towards the world x axis")
    parser.add_argument("--no-noise", dest="noise", action="store_false",
                        help="noise-free samples (to check the simulation itself)")
    parser.add_argument("--protocol", choices=PROTOCOLS, default="six-face")
    parser.add_argument("--poses", type=int, default=40,
                        help="random protocol: stops after the first rest")
    parser.add_argument("--move-angle-range-deg", type=_parse_range, default=(30.0, 120.0),
                        metavar="LO,HI", help="random protocol: each move's angle")
    parser.add_argument("--accel-step", type=lambda s: parse_step(s, "accel"), default=None,
                        help="quantisation step: m/s^2, or an LSB like 1/16384g")
    parser.add_argument("--gyro-step", type=lambda s: parse_step(s, "gyro"), default=None,
                        help="quantisation step: rad/s, or an LSB like 1/131deg")
    parser.add_argument("--turn-profile", choices=["smooth", "steady"], default="smooth",
                        help="rate profile of the turns about the vertical")
    parser.add_argument("--turn-rate-deg-s", type=float, default=96.0,
                        help="steady profile: the constant rate mid-turn (at most)")
    parser.add_argument("--turn-ramp-s", type=float, default=0.1,
                        help="steady profile: the ramp up to and down from the rate")
    parser.add_argument("--noisy-rest", type=int, default=None, metavar="POSE",
                        help="0-based pose held longer, with more noise")
    parser.add_argument("--noisy-rest-kind", choices=NOISY_REST_KINDS, default="hand")
    parser.add_argument("--noisy-rest-s", type=float, default=7.0)
    parser.add_argument("--noisy-rest-factor", type=float, default=5.0)
    parser.add_argument("--motor-hz", type=float, default=37.0)
    parser.add_argument("--settle-mg", type=float, default=1.0,
                        help="settling rest: the offset at its start, mg")
    parser.add_argument("--hold-range-s", type=_parse_range, default=None, metavar="LO,HI",
                        help="every hold after the first drawn uniformly in [LO, HI] s")
    parser.add_argument("--duplicate-face", type=_parse_duplicate, default=None,
                        metavar="FACE=OTHER", help="faces-once: FACE's pose holds OTHER's")
    parser.add_argument("--duplicate-angle-deg", type=float, default=0.005)
    parser.add_argument("--handling-s", type=float, default=0.0,
                        help="rest protocol: seconds of handling inside the rest")
    parser.add_argument("--handling-at-s", type=float, default=None,
                        help="rest protocol: when the handling starts (default 40%% in)")
    parser.add_argument("--handling-tilt-deg", type=float, default=2.0,
                        help="rest protocol: how far off the unit is set down")
    parser.add_argument("--gyro-random-walk", type=float, default=0.0, metavar="K",
                        help="gyro bias random walk, rad/s^2/sqrt(Hz)")
    parser.add_argument("--accel-random-walk", type=float, default=0.0, metavar="K",
                        help="accel bias random walk, m/s^3/sqrt(Hz)")
    parser.add_argument("--gyro-bias-shift", type=float, default=0.0, metavar="SIGMA",
                        help="a new gyro offset per axis (rad/s, Gaussian) at every move's middle")
    parser.add_argument("--temp-history", type=_parse_history, default=None, metavar="KIND:ARGS",
                        help="warmup:T0,T1,TAU, ramp:T0,T1 or plateau:T (degC, s)")
    parser.add_argument("--gyro-temp-quad", type=_parse_quad, action="append", default=[],
                        metavar="AXIS,C,TREF", help="C (T - TREF)^2 rad/s on the true rate")
    parser.add_argument("--accel-temp-quad", type=_parse_quad, action="append", default=[],
                        metavar="AXIS,C,TREF",
                        help="C (T - TREF)^2 m/s^2 on the true specific force")
    parser.add_argument("--gyro-rate-scale", type=_parse_rate_scale, action="append",
                        default=[], metavar="AXIS,S",
                        help="S |w| w rad/s on the true rate of AXIS (S per rad/s)")
    add_rest_arguments(parser)
    add_unit_arguments(parser)


def _floats(text):
    return [float(v) for v in text.split(",")]


def add_unit_arguments(parser):
    parser.add_argument("--unit-seed", type=int, default=None,
                        help="draw the unit from wide priors with this seed (the same seed, the "
                             "same unit: a calibration and a validation capture of one sensor)")


def add_rest_arguments(parser):
    """What makes a rest hard to tell from a turn (see the module's docstring)."""
    parser.add_argument("--move-profile", choices=["smooth", "steady"], default="smooth",
                        help="random and faces-once: the rate profile of every move")
    parser.add_argument("--hand-tremor-deg", type=float, default=0.0,
                        help="a hand's tremor: the orientation's RMS wobble per axis, deg")
    parser.add_argument("--hand-tremor-hz", type=_parse_range, default=(6.0, 11.0),
                        metavar="LO,HI", help="the tremor's frequencies")
    parser.add_argument("--slow-turn-every", type=int, default=0, metavar="K",
                        help="random: a slow steady turn about the vertical after every K-th "
                             "hold")
    parser.add_argument("--slow-turn-rate-range-deg-s", type=_parse_range, default=(24.0, 41.0),
                        metavar="LO,HI")
    parser.add_argument("--slow-turn-angles-deg", type=_floats, default=[360.0],
                        metavar="A1,A2,...", help="the slow turns' angles, in turn")
    parser.add_argument("--hold-bursts", type=float, default=0.0, metavar="FACTOR",
                        help="a rotation table's servo: vibration bursts during every hold, "
                             "FACTOR times the noise RMS")
    parser.add_argument("--hold-noise-factors", type=_floats, default=None, metavar="F0,F1,...",
                        help="the noise of hold k is F[k mod n] times the default")
    parser.add_argument("--single-faces", default="", metavar="FACE,...",
                        help="six-face: these faces are held once (no turned pose)")


def _extended(args):
    """Whether the truth carries the time ranges (kept off for the default capture, whose truth
    files the existing tests were written against)."""
    return (getattr(args, "full_truth", False) or args.protocol != "six-face" or
            args.accel_step is not None or args.gyro_step is not None or
            args.turn_profile != "smooth" or args.noisy_rest is not None or
            args.hold_range_s is not None or args.duplicate_face is not None or
            bool(getattr(args, "gyro_rate_scale", [])) or
            getattr(args, "move_profile", "smooth") != "smooth" or
            getattr(args, "hand_tremor_deg", 0.0) > 0 or getattr(args, "slow_turn_every", 0) > 0 or
            getattr(args, "hold_bursts", 0.0) > 0 or
            getattr(args, "hold_noise_factors", None) is not None or
            bool(getattr(args, "single_faces", "")))


def _tilt_to_face(r, face, g_world):
    """The 90-degree tilt about the horizontal body axis that brings `face` up: (axis, signed
    angle, new R_world_body). `up` is the table's normal in the body frame (the face resting on
    it), not gravity."""
    up = _transpose_times(r, [0.0, 0.0, 1.0])
    target = _unit_of_face(face)
    axis = [up[1] * target[2] - up[2] * target[1],
            up[2] * target[0] - up[0] * target[2],
            up[0] * target[1] - up[1] * target[0]]
    for sign in (1.0, -1.0):
        cand = _matmul(r, _axis_angle(axis, sign * math.pi / 2))
        if _face_label(_transpose_times(cand, g_world)) == face:
            return axis, sign * math.pi / 2, cand
    raise AssertionError(face)


def _steady_turn(angle, args, rate_deg_s=None):
    """Duration (a whole number of samples) and profile of a turn at a steady rate (at most
    rate_deg_s, default --turn-rate-deg-s)."""
    dt = 1.0 / args.rate_hz
    n_ramp = max(1, int(round(args.turn_ramp_s * args.rate_hz)))
    rate_max = math.radians(rate_deg_s if rate_deg_s is not None else args.turn_rate_deg_s)
    # The trapezoid's area is rate * (middle + ramp): the middle gets the fewest whole samples
    # that keep the rate at or below rate_max.
    n_mid = max(0, math.ceil(abs(angle) / rate_max / dt - n_ramp - 1e-9))
    rate = angle / ((n_mid + n_ramp) * dt)
    profile = {"kind": "steady", "ramp_s": n_ramp * dt, "middle_s": n_mid * dt, "rate": rate}
    return (2 * n_ramp + n_mid) * dt, profile


def _move_angle_rate(profile, angle, dur, t):
    """(angle turned so far, rate) at time t into a move of `angle` rad lasting dur s."""
    if profile == "smooth":
        tau = t / dur
        return (angle * (tau - math.sin(2 * math.pi * tau) / (2 * math.pi)),
                angle / dur * (1.0 - math.cos(2 * math.pi * tau)))
    ramp, rate = profile["ramp_s"], profile["rate"]
    if t < ramp:
        return rate * t * t / (2 * ramp), rate * t / ramp
    if t <= dur - ramp:
        return rate * (ramp / 2 + t - ramp), rate
    s = dur - t
    return angle - rate * s * s / (2 * ramp), rate * s / ramp


class _Holds:
    """Each pose's hold in seconds: the first (the noise is learnt on it), the noisy rest's, a
    draw from --hold-range-s (its own generator, so the noise stream does not depend on it), or
    --hold-s."""

    def __init__(self, args):
        self.args = args
        self.rng = random.Random(args.seed * 1000003 + 11)

    def __call__(self, pose):
        a = self.args
        if pose == a.noisy_rest:
            return a.noisy_rest_s
        if pose == 0:
            return a.first_hold_s
        if a.hold_range_s is not None:
            return self.rng.uniform(*a.hold_range_s)
        return a.hold_s


def _up_entry(face, r, g_world, gravity):
    return {"face": face, "up_body": [round(c / gravity, 12)
                                      for c in _transpose_times(r, g_world)]}


def _six_face(args, rng, g_world, hold_for):
    """The pairs protocol: (segments, poses, turn errors)."""
    segments = []
    poses = []
    turn_errors_deg = []
    r = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]  # R_world_body, Z+ up
    for i, face in enumerate(FACE_ORDER):
        if i > 0:
            axis, angle, r = _tilt_to_face(r, face, g_world)
            segments.append(("move", args.move_s, axis, angle, "smooth"))
        segments.append(("hold", hold_for(len(poses)), len(poses)))
        poses.append(_up_entry(face, r, g_world, args.gravity))
        if face in [f for f in args.single_faces.split(",") if f]:
            continue
        # The 180-degree turn about the vertical (the up body axis), with a hand's error.
        up_axis = _unit_of_face(face)
        turn_errors_deg.append(rng.gauss(0.0, args.turn_error_deg))
        turn = math.pi + math.radians(turn_errors_deg[-1])
        if args.turn_profile == "steady":
            dur, profile = _steady_turn(turn, args)
        else:
            dur, profile = args.move_s, "smooth"
        segments.append(("move", dur, up_axis, turn, profile))
        r = _matmul(r, _axis_angle(up_axis, turn))
        segments.append(("hold", hold_for(len(poses)), len(poses)))
        poses.append(_up_entry(face + " turned", r, g_world, args.gravity))
    for axis, angle_deg in (EXTRA_TILTS if args.extra_poses else []):
        segments.append(("move", args.move_s, list(axis), math.radians(angle_deg), "smooth"))
        r = _matmul(r, _axis_angle(list(axis), math.radians(angle_deg)))
        segments.append(("hold", hold_for(len(poses)), len(poses)))
        up = [c / args.gravity for c in _transpose_times(r, g_world)]
        on_face = max(abs(c) for c in up) > math.cos(math.radians(20))
        poses.append({"face": (_face_label(up) if on_face else "") + " extra",
                      "up_body": [round(c, 12) for c in up]})
    return segments, poses, turn_errors_deg, [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]


def _moves_through(orientations, args, g_world, hold_for, faces):
    """Segments visiting R_world_body orientations in order, each move one rotation about a
    body axis (the log of the relative rotation), the poses as sampled, and the orientation the
    capture starts in."""
    segments, poses = [], []
    r = orientations[0]
    slow_rng = random.Random(args.seed * 1000003 + 83)
    slow_count = 0
    for k, target in enumerate(orientations):
        if k > 0:
            axis, angle = _rotation_log(_matmul(_transpose(r), target))
            if args.move_profile == "steady":
                dur, profile = _steady_turn(angle, args)
            else:
                dur, profile = args.move_s, "smooth"
            segments.append(("move", dur, axis, angle, profile))
            r = _matmul(r, _axis_angle(axis, angle))
        segments.append(("hold", hold_for(k), k))
        poses.append(_up_entry(faces[k], r, g_world, args.gravity))
        every = args.slow_turn_every
        if every > 0 and (k + 1) % every == 0 and k + 1 < len(orientations):
            # About the table's normal: body axis R^T z_world.
            up = _transpose_times(r, [0.0, 0.0, 1.0])
            angles = args.slow_turn_angles_deg
            angle = math.radians(angles[slow_count % len(angles)])
            slow_count += 1
            dur, profile = _steady_turn(angle, args,
                                        slow_rng.uniform(*args.slow_turn_rate_range_deg_s))
            profile["slow"] = True
            segments.append(("move", dur, up, angle, profile))
            r = _matmul(r, _axis_angle(up, angle))
    return segments, poses, orientations[0]


def _faces_once(args, g_world, hold_for):
    orientations = []
    r = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    for i, face in enumerate(FACE_ORDER):
        if i > 0:
            _, _, r = _tilt_to_face(r, face, g_world)
        orientations.append(r)
    if args.duplicate_face:
        face, other = args.duplicate_face
        j = FACE_ORDER.index(other)
        # A horizontal body axis of OTHER's orientation: the next body axis after its up one.
        up = "XYZ".index(other[0])
        perp = [1.0 if i == (up + 1) % 3 else 0.0 for i in range(3)]
        orientations[FACE_ORDER.index(face)] = _matmul(
            orientations[j], _axis_angle(perp, math.radians(args.duplicate_angle_deg)))
    segments, poses, r0 = _moves_through(orientations, args, g_world, hold_for, FACE_ORDER)
    for p in poses:
        # The face each pose was meant for (its file's name) and the one it actually holds.
        p["meant_face"] = p["face"]
        p["face"] = _face_label(p["up_body"])
    return segments, poses, r0


def _random(args, g_world, hold_for):
    orient_rng = random.Random(args.seed * 1000003 + 29)
    r = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    orientations, faces = [r], ["Z+"]
    lo, hi = args.move_angle_range_deg
    for _ in range(args.poses):
        v = [orient_rng.gauss(0.0, 1.0) for _ in range(3)]
        n = math.sqrt(sum(x * x for x in v))
        angle = math.radians(orient_rng.uniform(lo, hi)) * orient_rng.choice((-1.0, 1.0))
        r = _matmul(r, _axis_angle([x / n for x in v], angle))
        orientations.append(r)
        up = _transpose_times(r, [0.0, 0.0, 1.0])
        faces.append(_face_label(up) if max(abs(c) for c in up) > math.cos(math.radians(20))
                     else "")
    return _moves_through(orientations, args, g_world, hold_for, faces)


def _rest(args, g_world):
    """One hold; with --handling-s, picked up and put down inside it (two holds)."""
    r0 = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    if args.handling_s <= 0:
        return [("hold", args.first_hold_s, 0)], [_up_entry("Z+", r0, g_world, args.gravity)], r0
    rng = random.Random(args.seed * 1000003 + 97)
    at = args.handling_at_s if args.handling_at_s is not None else 0.4 * args.first_hold_s
    moves, r = [], r0
    for _ in range(3):
        v = [rng.gauss(0.0, 1.0) for _ in range(3)]
        n = math.sqrt(sum(x * x for x in v))
        axis = [x / n for x in v]
        angle = math.radians(rng.uniform(20.0, 60.0)) * rng.choice((-1.0, 1.0))
        moves.append(("move", args.handling_s / 4, axis, angle, "smooth"))
        r = _matmul(r, _axis_angle(axis, angle))
    # Set down off the first orientation by the tilt, about a horizontal axis.
    tilt = rng.uniform(0.0, 2 * math.pi)
    target = _matmul(r0, _axis_angle([math.cos(tilt), math.sin(tilt), 0.0],
                                     math.radians(args.handling_tilt_deg)))
    axis, angle = _rotation_log(_matmul(_transpose(r), target))
    moves.append(("move", args.handling_s / 4, axis, angle, "smooth"))
    segments = ([("hold", at, 0)] + moves +
                [("hold", args.first_hold_s - at - args.handling_s, 1)])
    poses = [_up_entry("Z+", r0, g_world, args.gravity),
             _up_entry("Z+ after handling", target, g_world, args.gravity)]
    return segments, poses, r0


def simulate(args):
    """Returns (samples, truth): samples are (t_s, gyro_raw[3], accel_raw[3]) in rad/s and
    m/s^2 input units; truth is a JSON-ready dict of what was used."""
    rng = random.Random(args.seed)
    accel_bias = [0.15, -0.22, 0.31]       # m/s^2 (input units)
    accel_scale = [1.021, 0.984, 1.012]    # inverse model: y = scale (u - bias)
    gyro_bias = [0.012, -0.008, 0.005]     # rad/s
    gyro_scale = [1.03, 0.975, 1.015]
    unit = _WideUnit(args.unit_seed) if getattr(args, "unit_seed", None) is not None else None
    if unit:
        accel_bias, accel_scale = unit.accel_bias, unit.accel_scale
        gyro_bias, gyro_scale = unit.gyro_bias, unit.gyro_scale
    dt = 1.0 / args.rate_hz
    # Specific force at rest: up, magnitude g. The box rests on a table whose normal is world z
    # (the turns are about it); a tilted table leans the vertical away from that normal.
    tilt = math.radians(args.floor_tilt_deg)
    g_world = [args.gravity * math.sin(tilt), 0.0, args.gravity * math.cos(tilt)]
    if args.duplicate_face and args.protocol != "faces-once":
        raise ValueError("--duplicate-face needs --protocol faces-once")
    hold_for = _Holds(args)

    # The motion as segments: ("hold", seconds, pose) or ("move", seconds, body axis, angle,
    # profile).
    turn_errors_deg = []
    if args.protocol == "six-face":
        segments, poses, turn_errors_deg, r0 = _six_face(args, rng, g_world, hold_for)
    elif args.protocol == "faces-once":
        segments, poses, r0 = _faces_once(args, g_world, hold_for)
    elif args.protocol == "rest":
        segments, poses, r0 = _rest(args, g_world)
    else:
        segments, poses, r0 = _random(args, g_world, hold_for)

    # The noisy rest's extra noise has its own generator: the other poses' noise is unchanged.
    extra_rng = random.Random(args.seed * 1000003 + 53)
    noisy = _NoisyRest(args, extra_rng) if args.noisy_rest is not None else None
    tremor = _Tremor(args) if getattr(args, "hand_tremor_deg", 0.0) > 0 else None
    bursts = _Bursts(args) if getattr(args, "hold_bursts", 0.0) > 0 else None
    factors = getattr(args, "hold_noise_factors", None)

    history = getattr(args, "temp_history", None)
    quads = (getattr(args, "gyro_temp_quad", []), getattr(args, "accel_temp_quad", []))
    if (quads[0] or quads[1]) and history is None:
        raise ValueError("--gyro-temp-quad and --accel-temp-quad need --temp-history")
    total = sum(int(round(seg[1] * args.rate_hz)) for seg in segments)
    duration = (total - 1) * dt
    # The bias that moves with the unit: its own generator, so the noise stream is unchanged.
    shift_sigma = getattr(args, "gyro_bias_shift", 0.0)
    shift_rng = random.Random(args.seed * 1000003 + 71)
    shift = [0.0, 0.0, 0.0]
    hold_shifts = []
    # The bias random walks: their own generator, so the noise stream is unchanged.
    walk_rng = random.Random(args.seed * 1000003 + 89)
    walk_k = (getattr(args, "gyro_random_walk", 0.0), getattr(args, "accel_random_walk", 0.0))
    walk = ([0.0, 0.0, 0.0], [0.0, 0.0, 0.0])

    # Sample the segments. Rotations restart from the pose at the segment start, so the
    # orientation is exact (no integration drift), and the body rate is axis * dtheta/dt.
    samples = []
    moves = []
    r = r0
    k = 0
    for seg in segments:
        n = int(round(seg[1] * args.rate_hz))
        if seg[0] == "hold":
            poses[seg[2]]["t_start_s"] = k * dt
            poses[seg[2]]["t_end_s"] = (k + n - 1) * dt
            hold_shifts.append(list(shift))
        else:
            _, dur, axis, angle, profile = seg
            moves.append({"t_start_s": k * dt, "t_end_s": (k + n - 1) * dt,
                          "axis_body": axis, "angle_deg": math.degrees(angle),
                          "profile": "smooth" if profile == "smooth" else "steady"})
            if profile != "smooth":
                moves[-1].update({"ramp_s": profile["ramp_s"], "middle_s": profile["middle_s"],
                                  "rate_deg_s": math.degrees(profile["rate"]),
                                  "slow_turn": bool(profile.get("slow"))})
        for j in range(n):
            if seg[0] == "hold":
                rot, w_body = r, [0.0, 0.0, 0.0]
            else:
                # Mid-sample: the rate profile is sampled fairly (exactly, for the smooth
                # profile's full cosine period and for a ramp whose ends fall between samples).
                theta, rate = _move_angle_rate(profile, angle, dur, (j + 0.5) * dt)
                rot = _matmul(r, _axis_angle(axis, theta))
                w_body = [a * rate for a in axis]
            f_body = _transpose_times(rot, g_world)
            if tremor:
                d, d_rate = tremor.at(k * dt)
                f_body = [f_body[i] - (d[(i + 1) % 3] * f_body[(i + 2) % 3] -
                                       d[(i + 2) % 3] * f_body[(i + 1) % 3]) for i in range(3)]
                w_body = [w_body[i] + d_rate[i] for i in range(3)]
            temp = _temperature(history, k * dt, duration) if history else None
            # The rate scale acts on the turn itself; the bias shift is added after it.
            rate_scales = getattr(args, "gyro_rate_scale", [])
            if rate_scales:
                w_true = list(w_body)
                w_body = list(w_body)
                for axis_i, scale_s in rate_scales:
                    w_body[axis_i] += scale_s * abs(w_true[axis_i]) * w_true[axis_i]
            if shift_sigma > 0 and seg[0] == "move" and j == n // 2:
                shift = [shift_rng.gauss(0.0, shift_sigma) for _ in range(3)]
            if shift_sigma > 0:
                w_body = [w_body[i] + shift[i] for i in range(3)]
            if history:
                w_body = list(w_body)
                f_body = list(f_body)
                for axis_i, c, ref in quads[0]:
                    w_body[axis_i] += c * (temp - ref) ** 2
                for axis_i, c, ref in quads[1]:
                    f_body[axis_i] += c * (temp - ref) ** 2
            nf = factors[seg[2] % len(factors)] if factors and seg[0] == "hold" else 1.0
            y = unit.accel_y(f_body) if unit else [f_body[i] / accel_scale[i] for i in range(3)]
            accel = [y[i] + accel_bias[i] +
                     (nf * rng.gauss(0.0, args.accel_noise) if args.noise else 0.0)
                     for i in range(3)]
            gyro = [w_body[i] / gyro_scale[i] + gyro_bias[i] +
                    (nf * rng.gauss(0.0, args.gyro_noise) if args.noise else 0.0)
                    for i in range(3)]
            if bursts and seg[0] == "hold":
                bursts.add(accel, gyro, seg[2], j * dt, n * dt)
            for w_i, k_walk in enumerate(walk_k):
                if k_walk > 0:
                    for i in range(3):
                        walk[w_i][i] += walk_rng.gauss(0.0, k_walk * math.sqrt(dt))
                    target_list = gyro if w_i == 0 else accel
                    for i in range(3):
                        target_list[i] += walk[w_i][i]
            if noisy and seg[0] == "hold" and seg[2] == args.noisy_rest:
                noisy.add(accel, gyro, (j + 0.5) * dt, n * dt)
            if args.accel_step is not None:
                accel = [round(v / args.accel_step) * args.accel_step for v in accel]
            if args.gyro_step is not None:
                gyro = [round(v / args.gyro_step) * args.gyro_step for v in gyro]
            samples.append((k * dt, gyro, accel) + ((temp,) if history else ()))
            k += 1
        if seg[0] == "move":
            r = _matmul(r, _axis_angle(seg[2], seg[3]))

    truth = {
        "protocol": args.protocol,
        "seed": args.seed,
        "rate_hz": args.rate_hz,
        "gravity_m_s2": args.gravity,
        "floor_tilt_deg": args.floor_tilt_deg,
        "turn_errors_deg": turn_errors_deg,
        "samples": len(samples),
        "poses": poses,
        "pose_count": len(poses),
        "hold_s": args.hold_s,
        "first_hold_s": args.first_hold_s,
        "move_s": args.move_s,
        "accel_noise_m_s2": args.accel_noise,
        "gyro_noise_rad_s": args.gyro_noise,
        "accel_bias_m_s2": accel_bias,
        "accel_scale": accel_scale,
        "gyro_bias_rad_s": gyro_bias,
        "gyro_scale": gyro_scale,
        "model": "u = y / scale + bias + noise per axis (inverse of y = scale (u - bias)), "
                 "no misalignment; accel in m/s^2, gyro in rad/s",
    }
    if unit:
        truth["accel_model"] = unit.truth()
    if walk_k[0] > 0 or walk_k[1] > 0:
        truth["random_walk"] = {"gyro_rad_s2_sqrt_hz": walk_k[0], "accel_m_s3_sqrt_hz": walk_k[1],
                                "model": "a Gaussian step of K sqrt(dt) per sample on every "
                                         "axis' bias"}
    if getattr(args, "handling_s", 0.0) > 0 and args.protocol == "rest":
        truth["handling"] = {"t_start_s": moves[0]["t_start_s"], "t_end_s": moves[-1]["t_end_s"],
                             "tilt_deg": args.handling_tilt_deg}
    if shift_sigma > 0:
        truth["gyro_bias_shift"] = {
            "sigma_rad_s": shift_sigma, "per_hold_rad_s": hold_shifts,
            "model": "a new offset per axis at each move's middle, added to the true rate"}
    if getattr(args, "gyro_rate_scale", []):
        truth["gyro_rate_scale"] = {
            "terms": [{"axis": "xyz"[a], "s_per_rad_s": sc} for a, sc in args.gyro_rate_scale],
            "model": "S |w| w added to the true rate w (rad/s) on AXIS before scale and bias"}
    if history:
        truth["temperature"] = {
            "history": {"kind": history[0], "values": history[1]},
            "gyro_temp_quad": [{"axis": "xyz"[a], "c_rad_s_per_degc2": c, "turnover_c": ref}
                               for a, c, ref in quads[0]],
            "accel_temp_quad": [{"axis": "xyz"[a], "c_m_s2_per_degc2": c, "turnover_c": ref}
                                for a, c, ref in quads[1]],
            "model": "C (T - TREF)^2 added to the true rate / specific force before scale and "
                     "bias"}
    if _extended(args):
        truth.update({
            "noise": args.noise,
            "accel_step_m_s2": args.accel_step,
            "gyro_step_rad_s": args.gyro_step,
            "quantisation": "u -> round(u / step) * step after the noise (half to even)",
            "turn_profile": args.turn_profile,
            "hold_range_s": args.hold_range_s,
            "moves": moves,
            "slow_turns": [m for m in moves if m.get("slow_turn")],
            "hand_tremor_deg": getattr(args, "hand_tremor_deg", 0.0),
            "hold_bursts": bursts.truth() if bursts else None,
            "hold_noise_factors": factors,
            "single_faces": getattr(args, "single_faces", ""),
            "noisy_rest": noisy.truth() if noisy else None,
            "duplicate_face": ({"face": args.duplicate_face[0],
                                "holds": args.duplicate_face[1],
                                "angle_deg": args.duplicate_angle_deg}
                               if args.duplicate_face else None),
            "times": "sample k at t = k / rate_hz s from the capture's first sample",
        })
    else:
        for p in poses:
            del p["t_start_s"], p["t_end_s"]
    return samples, truth


class _NoisyRest:
    """The extra noise of --noisy-rest (see the module's docstring)."""

    def __init__(self, args, rng):
        self.args = args
        self.rng = rng
        f = args.noisy_rest_factor
        extra = math.sqrt(max(0.0, f * f - 1.0)) if args.noise else f
        self.white = (extra * args.accel_noise, extra * args.gyro_noise)
        self.phases = [rng.uniform(0.0, 2 * math.pi) for _ in range(6)]
        self.d0 = args.settle_mg * 1e-3 * STANDARD_GRAVITY_M_S2
        self.tau = args.noisy_rest_s * SETTLE_MEAN_MG / args.settle_mg
        self.offsets = []

    def add(self, accel, gyro, t, hold_s):
        a = self.args
        kind = a.noisy_rest_kind
        if kind == "motor":
            amp = (math.sqrt(2) * a.noisy_rest_factor * a.accel_noise,
                   math.sqrt(2) * a.noisy_rest_factor * a.gyro_noise)
            w = 2 * math.pi * a.motor_hz * t
            for i in range(3):
                accel[i] += amp[0] * math.sin(w + self.phases[i])
                gyro[i] += amp[1] * math.sin(w + self.phases[3 + i])
            return
        env = self.envelope(t, hold_s)
        for i in range(3):
            accel[i] += self.rng.gauss(0.0, env * self.white[0])
        for i in range(3):
            gyro[i] += self.rng.gauss(0.0, env * self.white[1])
        if kind == "settling":
            d = self.d0 * math.exp(-t / self.tau)
            self.offsets.append(d)
            for i in range(3):
                accel[i] += d

    def envelope(self, t, hold_s):
        """The extra noise's amplitude over the hold, its RMS over the hold 1: a hand presses
        and relaxes (|sin| with a period of 2 HAND_PRESS_S), a settling sensor quietens
        (exp(-t / tau) with tau = hold / 3)."""
        if self.args.noisy_rest_kind == "hand":
            return math.sqrt(2.0) * abs(math.sin(math.pi * t / HAND_PRESS_S))
        tau = hold_s / 3.0
        rms = math.sqrt(tau / (2.0 * hold_s) * (1.0 - math.exp(-2.0 * hold_s / tau)))
        return math.exp(-t / tau) / rms

    def truth(self):
        a = self.args
        out = {"pose": a.noisy_rest, "kind": a.noisy_rest_kind, "hold_s": a.noisy_rest_s,
               "noise_factor": a.noisy_rest_factor}
        if a.noisy_rest_kind == "motor":
            out["motor_hz"] = a.motor_hz
        if a.noisy_rest_kind == "settling":
            out.update({"settle_start_m_s2": self.d0, "settle_tau_s": self.tau,
                        "settle_mean_offset_m_s2": (sum(self.offsets) / len(self.offsets)
                                                    if self.offsets else 0.0)})
        return out


class _Tremor:
    """A hand's tremor (--hand-tremor-deg): a small body-frame rotation d(t) and its rate."""

    def __init__(self, args):
        rng = random.Random(args.seed * 1000003 + 97)
        amp = math.radians(args.hand_tremor_deg)  # two sinusoids of amplitude amp: RMS amp
        self.parts = [[(amp, 2 * math.pi * rng.uniform(*args.hand_tremor_hz),
                        rng.uniform(0.0, 2 * math.pi)) for _ in range(2)] for _ in range(3)]

    def at(self, t):
        d = [sum(a * math.sin(w * t + p) for a, w, p in axis) for axis in self.parts]
        rate = [sum(a * w * math.cos(w * t + p) for a, w, p in axis) for axis in self.parts]
        return d, rate


class _Bursts:
    """A rotation table's servo (--hold-bursts): vibration bursts during each hold."""

    def __init__(self, args):
        self.args = args
        self.rng = random.Random(args.seed * 1000003 + 101)
        self.schedule = {}
        self.count = 0

    def _bursts(self, pose, hold_s):
        if pose not in self.schedule:
            out, t = [], self.rng.uniform(1.0, 4.0)
            while t < hold_s:
                d = self.rng.uniform(0.3, 1.2)
                out.append((t, t + d, [self.rng.uniform(0.0, 2 * math.pi) for _ in range(6)]))
                t += d + self.rng.uniform(2.0, 5.0)
            self.schedule[pose] = out
            self.count += len(out)
        return self.schedule[pose]

    def add(self, accel, gyro, pose, t, hold_s):
        a = self.args
        amp = (math.sqrt(2) * a.hold_bursts * a.accel_noise, math.sqrt(2) * a.hold_bursts *
               a.gyro_noise)
        for t0, t1, phases in self._bursts(pose, hold_s):
            if t0 <= t < t1:
                w = 2 * math.pi * a.motor_hz * t
                for i in range(3):
                    accel[i] += amp[0] * math.sin(w + phases[i])
                    gyro[i] += amp[1] * math.sin(w + phases[3 + i])

    def truth(self):
        return {"factor": self.args.hold_bursts, "motor_hz": self.args.motor_hz,
                "bursts": self.count,
                "model": "sinusoids at motor_hz, amplitude sqrt(2) factor noise, in bursts of "
                         "0.3-1.2 s every 2-5 s of each hold"}


class _WideUnit:
    """A unit drawn from wide priors (--unit-seed): the accelerometer's full model."""

    def __init__(self, seed):
        rng = random.Random(seed * 7919 + 3)
        self.accel_bias = [rng.uniform(-0.3, 0.3) for _ in range(3)]
        # imucal's scale is per input unit: y = scale (u - bias); the sensor's gain is 1 / scale.
        self.accel_scale = [1.0 + rng.uniform(-0.03, 0.03) for _ in range(3)]
        self.tri = [rng.uniform(-3e-3, 3e-3) for _ in range(3)]  # t_yx, t_zx, t_zy
        self.quad = [rng.choice((-1.0, 1.0)) * math.exp(rng.uniform(math.log(1e-5),
                                                                    math.log(3e-4)))
                     for _ in range(3)]
        self.gyro_bias = [rng.uniform(-0.02, 0.02) for _ in range(3)]
        self.gyro_scale = [1.0 + rng.uniform(-0.03, 0.03) for _ in range(3)]

    def accel_y(self, a):
        """The sensor's y (m/s^2 before scale) for a true specific force a (body, m/s^2)."""
        t_yx, t_zx, t_zy = self.tri
        z0 = a[0]
        z1 = a[1] - t_yx * z0
        z2 = a[2] - t_zx * z0 - t_zy * z1
        out = []
        for z, q in zip((z0, z1, z2), self.quad):
            y = z if q == 0 else (math.sqrt(1.0 + 4.0 * q * z) - 1.0) / (2.0 * q)
            out.append(y)
        return [out[i] / self.accel_scale[i] for i in range(3)]

    def truth(self):
        return {"bias": self.accel_bias, "scale": self.accel_scale, "tri_angles": self.tri,
                "quadratic": self.quad,
                "model": "imucal's: y = scale (u - bias), z = y + q y^2, a = L(tri) z"}
