// The live plot of one session: force and torque magnitude over the last
// 10 s, the device's commanded wrench (every servo tick, from telemetry) and
// the server's penalty wrench (every answer from telemetry; from the pose
// frames when the server sends no telemetry). Plain 2D canvas.

export const WINDOW_MS = 10000;

/// One series: sample times on the page's clock (performance.now(), ms) and values.
class Series {
  constructor(color, dashed) {
    this.color = color;
    this.dashed = dashed;
    this.t = [];
    this.v = [];
    this.head = 0;          // samples before head are out of the window
    this.offsetMs = null;   // sender clock (ms) -> page clock (ms)
  }

  /// Samples on the sender's clock: t0 (s) plus dt_us each; values `vals`.
  /// The offset to the page clock is the smallest seen (receipt minus the
  /// newest sample): queueing delay never pushes samples into the future.
  addBatch(t0, dtUs, vals, nowMs) {
    const n = Math.min(dtUs.length, vals.length);
    if (n === 0) return;
    const lastMs = t0 * 1e3 + dtUs[n - 1] * 1e-3;
    const off = nowMs - lastMs;
    if (this.offsetMs === null || off < this.offsetMs) this.offsetMs = off;
    for (let i = 0; i < n; ++i) this.push(t0 * 1e3 + dtUs[i] * 1e-3 + this.offsetMs, vals[i]);
  }

  push(tMs, value) {
    if (this.t.length > this.head && tMs < this.t[this.t.length - 1]) return;  // keep order
    this.t.push(tMs);
    this.v.push(value);
  }

  prune(nowMs) {
    const from = nowMs - WINDOW_MS;
    while (this.head < this.t.length && this.t[this.head] < from) ++this.head;
    if (this.head > 4096 && this.head * 2 > this.t.length) {
      this.t = this.t.slice(this.head);
      this.v = this.v.slice(this.head);
      this.head = 0;
    }
  }

  count() { return this.t.length - this.head; }

  max() {
    let m = 0;
    for (let i = this.head; i < this.v.length; ++i) if (this.v[i] > m) m = this.v[i];
    return m;
  }
}

function niceCeil(x) {
  if (!(x > 0)) return 1;
  const e = Math.pow(10, Math.floor(Math.log10(x)));
  for (const m of [1, 2, 5, 10]) if (x <= m * e) return m * e;
  return 10 * e;
}

export class SessionPlot {
  constructor(canvas) {
    this.canvas = canvas;
    this.force = { device: new Series('#ff5a3c', false), server: new Series('#ffd166', true) };
    this.torque = { device: new Series('#c266ff', false), server: new Series('#7fd7ff', true) };
    this.serverFromPoses = true;  // until telemetry brings the server's samples
  }

  addTelemetry(t, nowMs) {
    if (t.commanded) {
      const c = t.commanded;
      this.force.device.addBatch(c.t0, c.dt_us, c.f, nowMs);
      this.torque.device.addBatch(c.t0, c.dt_us, c.tau, nowMs);
    }
    if (t.server) {
      if (this.serverFromPoses) {  // switch sources: forget the pose-frame samples
        this.serverFromPoses = false;
        this.force.server = new Series('#ffd166', true);
        this.torque.server = new Series('#7fd7ff', true);
      }
      const s = t.server;
      this.force.server.addBatch(s.t0, s.dt_us, s.f, nowMs);
      this.torque.server.addBatch(s.t0, s.dt_us, s.tau, nowMs);
    }
  }

  /// A pose frame's probe force and torque (N, N m), used only while the
  /// server sends no telemetry.
  addPoseFrame(forceN, torqueNm, nowMs) {
    if (!this.serverFromPoses) return;
    this.force.server.push(nowMs, forceN);
    if (torqueNm !== null) this.torque.server.push(nowMs, torqueNm);
  }

  /// Samples in the window, all series.
  samples(nowMs) {
    let n = 0;
    for (const s of this.all()) { s.prune(nowMs); n += s.count(); }
    return n;
  }

  all() { return [this.force.device, this.force.server, this.torque.device, this.torque.server]; }

  draw(nowMs) {
    const c = this.canvas;
    const dpr = window.devicePixelRatio || 1;
    const w = Math.round(c.clientWidth * dpr), h = Math.round(c.clientHeight * dpr);
    if (w === 0 || h === 0) return;
    if (c.width !== w || c.height !== h) { c.width = w; c.height = h; }
    // A CPU canvas: in software WebGL (SwiftShader) an accelerated 2D canvas
    // costs the page most of its frame rate.
    const g = c.getContext('2d', { willReadFrequently: true });
    g.setTransform(dpr, 0, 0, dpr, 0, 0);
    const W = c.clientWidth, H = c.clientHeight;
    g.clearRect(0, 0, W, H);
    g.fillStyle = 'rgba(0,0,0,0.25)';
    g.fillRect(0, 0, W, H);
    const half = H / 2;
    this.panel(g, 0, half, W, this.force, 'N', nowMs);
    this.panel(g, half, half, W, this.torque, 'N m', nowMs);
  }

  panel(g, y0, h, W, pair, unit, nowMs) {
    const left = 34, top = y0 + 3, bottom = y0 + h - 3, width = W - left - 4;
    pair.device.prune(nowMs);
    pair.server.prune(nowMs);
    const ymax = niceCeil(Math.max(pair.device.max(), pair.server.max(), 1e-6) * 1.05);
    g.strokeStyle = '#3a4048';
    g.lineWidth = 1;
    g.strokeRect(left + 0.5, top + 0.5, width, bottom - top);
    g.fillStyle = '#9aa';
    g.font = '10px system-ui, sans-serif';
    g.fillText(`${+ymax.toPrecision(3)}`, 2, top + 9);
    g.fillText(unit, 2, bottom - 2);
    const x = t => left + width * (1 - (nowMs - t) / WINDOW_MS);
    const y = v => bottom - (bottom - top) * Math.min(1, v / ymax);
    for (const s of [pair.server, pair.device]) {
      if (s.count() === 0) continue;
      g.strokeStyle = s.color;
      g.setLineDash(s.dashed ? [4, 3] : []);
      g.beginPath();
      // At most about two points per pixel column: the max of each column keeps peaks.
      const n = s.count(), step = Math.max(1, Math.floor(n / (2 * width)));
      for (let i = s.head; i < s.t.length; i += step) {
        let v = s.v[i];
        for (let k = 1; k < step && i + k < s.v.length; ++k) v = Math.max(v, s.v[i + k]);
        if (i === s.head) g.moveTo(x(s.t[i]), y(v)); else g.lineTo(x(s.t[i]), y(v));
      }
      g.stroke();
    }
    g.setLineDash([]);
  }
}
