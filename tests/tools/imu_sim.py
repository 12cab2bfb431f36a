"""A six-face calibration capture simulated from first principles, for the importer writers.

Shared by write_rosbag2.py and write_euroc.py (standard library only, nothing from imucal): the
body is held on each face twice, the second time turned 180 degrees about the vertical, with
smooth rotations about one body axis in between, so the gyroscope reading of a move integrates
exactly to the rotation between its two poses; the table is tilted a little (a pair's two up
directions differ) and a hand's 180-degree turn is a few degrees off. Four extra poses follow
the pairs (EXTRA_TILTS). The sensor reads the inverse of imucal's documented model with no
misalignment (README "The model and its conventions"):
    y = scale * (u - bias)  =>  u = y / scale + bias + white noise
per axis, for the specific force (m/s^2) and the angular rate (rad/s).
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


def _matmul(a, b):
    return [[sum(a[i][k] * b[k][j] for k in range(3)) for j in range(3)] for i in range(3)]


def _transpose_times(r, v):
    """R^T v: a world vector in the body frame."""
    return [sum(r[k][i] * v[k] for k in range(3)) for i in range(3)]


def _axis_angle(axis, angle_rad):
    """Rodrigues: rotation by angle_rad about the unit vector axis."""
    x, y, z = axis
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    t = 1.0 - c
    return [[t * x * x + c, t * x * y - s * z, t * x * z + s * y],
            [t * x * y + s * z, t * y * y + c, t * y * z - s * x],
            [t * x * z - s * y, t * y * z + s * x, t * z * z + c]]


def _face_label(up_body):
    axis = max(range(3), key=lambda i: abs(up_body[i]))
    return "XYZ"[axis] + ("+" if up_body[axis] > 0 else "-")


def _unit_of_face(label):
    v = [0.0, 0.0, 0.0]
    v["XYZ".index(label[0])] = 1.0 if label[1] == "+" else -1.0
    return v


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


def simulate(args):
    """Returns (samples, truth): samples are (t_s, gyro_raw[3], accel_raw[3]) in rad/s and
    m/s^2 input units; truth is a JSON-ready dict of what was used."""
    rng = random.Random(args.seed)
    accel_bias = [0.15, -0.22, 0.31]       # m/s^2 (input units)
    accel_scale = [1.021, 0.984, 1.012]    # inverse model: y = scale (u - bias)
    gyro_bias = [0.012, -0.008, 0.005]     # rad/s
    gyro_scale = [1.03, 0.975, 1.015]
    dt = 1.0 / args.rate_hz
    # Specific force at rest: up, magnitude g. The box rests on a table whose normal is world z
    # (the turns are about it); a tilted table leans the vertical away from that normal.
    tilt = math.radians(args.floor_tilt_deg)
    g_world = [args.gravity * math.sin(tilt), 0.0, args.gravity * math.cos(tilt)]

    # The motion as segments: ("hold", seconds) or ("move", seconds, body axis, angle).
    segments = []
    poses = []
    turn_errors_deg = []
    r = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]  # R_world_body, Z+ up
    for i, face in enumerate(FACE_ORDER):
        if i > 0:
            # Tilt 90 degrees about the horizontal body axis that brings `face` up. `up` is the
            # table's normal in the body frame (the face resting on it), not gravity.
            up = _transpose_times(r, [0.0, 0.0, 1.0])
            target = _unit_of_face(face)
            axis = [up[1] * target[2] - up[2] * target[1],
                    up[2] * target[0] - up[0] * target[2],
                    up[0] * target[1] - up[1] * target[0]]
            chosen = None
            for sign in (1.0, -1.0):
                cand = _matmul(r, _axis_angle(axis, sign * math.pi / 2))
                if _face_label(_transpose_times(cand, g_world)) == face:
                    chosen = (sign, cand)
                    break
            assert chosen, face
            segments.append(("move", args.move_s, axis, chosen[0] * math.pi / 2))
            r = chosen[1]
        hold = args.first_hold_s if i == 0 else args.hold_s
        segments.append(("hold", hold))
        poses.append({"face": face, "up_body": [round(c / args.gravity, 12)
                                                for c in _transpose_times(r, g_world)]})
        # The 180-degree turn about the vertical (the up body axis), with a hand's error.
        up_axis = _unit_of_face(face)
        turn_errors_deg.append(rng.gauss(0.0, args.turn_error_deg))
        turn = math.pi + math.radians(turn_errors_deg[-1])
        segments.append(("move", args.move_s, up_axis, turn))
        r = _matmul(r, _axis_angle(up_axis, turn))
        segments.append(("hold", args.hold_s))
        poses.append({"face": face + " turned", "up_body": [
            round(c / args.gravity, 12) for c in _transpose_times(r, g_world)]})
    for axis, angle_deg in (EXTRA_TILTS if args.extra_poses else []):
        segments.append(("move", args.move_s, list(axis), math.radians(angle_deg)))
        r = _matmul(r, _axis_angle(list(axis), math.radians(angle_deg)))
        segments.append(("hold", args.hold_s))
        up = [c / args.gravity for c in _transpose_times(r, g_world)]
        on_face = max(abs(c) for c in up) > math.cos(math.radians(20))
        poses.append({"face": (_face_label(up) if on_face else "") + " extra",
                      "up_body": [round(c, 12) for c in up]})

    # Sample the segments. Rotations restart from the pose at the segment start, so the
    # orientation is exact (no integration drift), and the body rate is axis * dtheta/dt.
    samples = []
    r = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    k = 0
    for seg in segments:
        n = int(round(seg[1] * args.rate_hz))
        for j in range(n):
            if seg[0] == "hold":
                rot, w_body = r, [0.0, 0.0, 0.0]
            else:
                _, dur, axis, angle = seg
                tau = (j + 0.5) * dt / dur  # mid-sample: the rate profile is sampled fairly
                theta = angle * (tau - math.sin(2 * math.pi * tau) / (2 * math.pi))
                rate = angle / dur * (1.0 - math.cos(2 * math.pi * tau))
                rot = _matmul(r, _axis_angle(axis, theta))
                w_body = [a * rate for a in axis]
            f_body = _transpose_times(rot, g_world)
            accel = [f_body[i] / accel_scale[i] + accel_bias[i] +
                     (rng.gauss(0.0, args.accel_noise) if args.noise else 0.0) for i in range(3)]
            gyro = [w_body[i] / gyro_scale[i] + gyro_bias[i] +
                    (rng.gauss(0.0, args.gyro_noise) if args.noise else 0.0) for i in range(3)]
            samples.append((k * dt, gyro, accel))
            k += 1
        if seg[0] == "move":
            r = _matmul(r, _axis_angle(seg[2], seg[3]))

    truth = {
        "protocol": "six-face",
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
    return samples, truth
