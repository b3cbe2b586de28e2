// Poses: quaternion and matrix helpers (x, y, z, w; the server's conventions), a sampled trace
// interpolated in time, and a mouse-and-keyboard controller.

export function quatNormalize(q) {
  const n = Math.hypot(q[0], q[1], q[2], q[3]) || 1;
  return [q[0] / n, q[1] / n, q[2] / n, q[3] / n];
}

export function quatMul(a, b) {
  const [ax, ay, az, aw] = a, [bx, by, bz, bw] = b;
  return [aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
          aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz];
}

export function quatAxisAngle(axis, rad) {
  const s = Math.sin(rad / 2);
  return [axis[0] * s, axis[1] * s, axis[2] * s, Math.cos(rad / 2)];
}

// 3x3 rotation matrix of a unit quaternion, row-major [[r00, r01, r02], ...]
export function quatToMat3(q) {
  const [x, y, z, w] = quatNormalize(q);
  return [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
          [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
          [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]];
}

export function slerp(a, b, u) {
  let d = a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3];
  const s = d < 0 ? -1 : 1;
  d = Math.abs(d);
  if (d > 0.9995) {
    return quatNormalize([0, 1, 2, 3].map(i => a[i] + u * (s * b[i] - a[i])));
  }
  const th = Math.acos(d), sn = Math.sin(th);
  const wa = Math.sin((1 - u) * th) / sn, wb = s * Math.sin(u * th) / sn;
  return [0, 1, 2, 3].map(i => wa * a[i] + wb * b[i]);
}

// A trace as the server samples it ({t: [s], p: [[x,y,z]], q: [[x,y,z,w]]}); poseAt clamps to its ends.
export class Trace {
  constructor(json) {
    this.name = json.name; this.t = json.t; this.p = json.p; this.q = json.q;
    this.duration = json.duration_s;
  }
  poseAt(ts) {
    const t = this.t, n = t.length;
    if (ts <= t[0]) return { p: this.p[0].slice(), q: this.q[0].slice() };
    if (ts >= t[n - 1]) return { p: this.p[n - 1].slice(), q: this.q[n - 1].slice() };
    let lo = 0, hi = n - 1;
    while (hi - lo > 1) { const mid = (lo + hi) >> 1; if (t[mid] <= ts) lo = mid; else hi = mid; }
    const u = (ts - t[lo]) / (t[hi] - t[lo]);
    const a = this.p[lo], b = this.p[hi];
    return { p: [0, 1, 2].map(i => a[i] + u * (b[i] - a[i])), q: slerp(this.q[lo], this.q[hi], u) };
  }
}

// Mouse drag turns (yaw about world up, pitch about the camera's right), W/A/S/D/Q/E move at speed m/s.
export class Controls {
  constructor(el, start, speed = 1.4) {
    this.p = start.p.slice(); this.yaw = 0; this.pitch = 0; this.base = start.q.slice(); this.speed = speed;
    this.keys = new Set(); this.last = null;
    el.addEventListener('mousemove', e => {
      if (!(e.buttons & 1)) return;
      this.yaw -= e.movementX * 0.004; this.pitch = Math.max(-1.4, Math.min(1.4, this.pitch - e.movementY * 0.004));
    });
    window.addEventListener('keydown', e => this.keys.add(e.key.toLowerCase()));
    window.addEventListener('keyup', e => this.keys.delete(e.key.toLowerCase()));
  }
  poseAt(tSec) {
    const dt = this.last === null ? 0 : Math.min(0.1, tSec - this.last);
    this.last = tSec;
    const q = quatNormalize(quatMul(quatMul(quatAxisAngle([0, 1, 0], this.yaw), this.base), quatAxisAngle([1, 0, 0], this.pitch)));
    const m = quatToMat3(q);
    const fwd = [-m[0][2], -m[1][2], -m[2][2]], right = [m[0][0], m[1][0], m[2][0]];
    const k = this.keys, v = this.speed * dt;
    const go = (d, s) => { for (let i = 0; i < 3; i++) this.p[i] += d[i] * s; };
    if (k.has('w')) go(fwd, v); if (k.has('s')) go(fwd, -v);
    if (k.has('d')) go(right, v); if (k.has('a')) go(right, -v);
    if (k.has('e')) this.p[1] += v; if (k.has('q')) this.p[1] -= v;
    return { p: this.p.slice(), q };
  }
}
