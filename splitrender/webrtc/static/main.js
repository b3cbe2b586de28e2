// splitrender's browser client: WebRTC in, WebGL 2 out, scored like the headless client.
//
// URL parameters start a session without the form (what the tests do): method, trace (a built-in trace or
// "manual"), duration (s), width, height, record_every (read back every Nth displayed frame; 0 = none),
// autostart=1.  window.splitrender.done resolves with the session's result.
//
// A server started with --token wants it on every /api/ call: the page takes it from its URL (#token=... keeps it
// out of the server's and proxies' logs; ?token=... works too) or, answered 401, asks for it, and sends it as
// "Authorization: Bearer TOKEN".
import { Trace, Controls } from './pose.js';
import { makeDisplay, parseSlotMessage } from './methods.js';

const $ = sel => document.querySelector(sel);
const state = { phase: 'idle', error: null, result: null };
let resolveDone;
window.splitrender = { state, done: new Promise(r => { resolveDone = r; }) };

function fail(err) {
  const text = err && err.message ? err.message : String(err);
  state.phase = 'failed'; state.error = text;
  $('#error').textContent = text;
  resolveDone({ ok: false, error: text });
}

// serve --token: from the URL's fragment or query, else asked for when the server answers 401
let token = new URLSearchParams(location.hash.slice(1)).get('token') || new URLSearchParams(location.search).get('token');
const authHeaders = () => (token ? { Authorization: `Bearer ${token}` } : {});

async function api(url, init = {}) {
  for (let asked = false; ; asked = true) {
    const r = await fetch(url, { cache: 'no-store', ...init, headers: { ...(init.headers || {}), ...authHeaders() } });
    if (r.status !== 401 || asked) return r;
    const given = window.prompt('This server needs its token (serve --token):');
    if (!given) return r;
    token = given;
  }
}

async function getJSON(url) {
  const r = await api(url);
  const body = await r.json();
  if (!r.ok) throw new Error(`${url}: ${body.error || r.status}`);
  return body;
}

async function postJSON(url, obj) {
  const r = await api(url, { method: 'POST', headers: { 'Content-Type': 'application/json' }, body: JSON.stringify(obj) });
  const body = await r.json();
  if (!r.ok) throw new Error(`${url}: ${body.error || r.status}`);
  return body;
}

// server clock - page clock (ms), from the fastest of a few round trips
async function clockOffset() {
  let best = null;
  for (let i = 0; i < 5; i++) {
    const a = performance.timeOrigin + performance.now();
    const { server_ms } = await getJSON('/api/clock');
    const b = performance.timeOrigin + performance.now();
    if (!best || b - a < best.rtt) best = { rtt: b - a, offset: server_ms - (a + b) / 2 };
  }
  return best.offset;
}

function gatheringDone(pc) {
  if (pc.iceGatheringState === 'complete') return Promise.resolve();
  return new Promise(resolve => {
    const check = () => { if (pc.iceGatheringState === 'complete') resolve(); };
    pc.addEventListener('icegatheringstatechange', check);
    setTimeout(resolve, 3000);      // what has been gathered by then
  });
}

function opened(channel) {
  return channel.readyState === 'open' ? Promise.resolve()
    : new Promise((resolve, reject) => {
      channel.addEventListener('open', resolve, { once: true });
      channel.addEventListener('close', () => reject(new Error(`data channel ${channel.label} closed`)), { once: true });
    });
}

// The browser's own view of the video stream (getStats: inbound-rtp), the figures the tests set beside the server's.
async function inboundStats(pc) {
  const out = {};
  (await pc.getStats()).forEach(s => {
    if (s.type === 'inbound-rtp' && s.kind === 'video') {
      for (const k of ['framesDecoded', 'framesReceived', 'framesDropped', 'keyFramesDecoded', 'nackCount', 'pliCount',
                       'firCount', 'packetsLost', 'packetsReceived', 'bytesReceived', 'totalDecodeTime',
                       'jitterBufferDelay', 'jitterBufferEmittedCount', 'framesPerSecond']) {
        if (typeof s[k] === 'number') out[k] = s[k];
      }
      if (s.decoderImplementation) out.decoder = s.decoderImplementation;
    }
    if (s.type === 'candidate-pair' && s.nominated && typeof s.currentRoundTripTime === 'number') {
      out.rttMs = s.currentRoundTripTime * 1000;
    }
  });
  return out;
}

async function run(opts) {
  state.phase = 'connecting';
  const offset = await clockOffset();
  const serverNow = () => performance.timeOrigin + performance.now() + offset;
  let source;
  if (opts.trace === 'manual') {
    const start = new Trace(await getJSON(`/api/trace?name=static&duration_s=1&width=${opts.width}&height=${opts.height}`));
    source = new Controls($('#view'), start.poseAt(0));
  } else {
    source = new Trace(await getJSON(`/api/trace?name=${encodeURIComponent(opts.trace)}&duration_s=${opts.duration}` +
                                     `&width=${opts.width}&height=${opts.height}`));
  }

  const pc = new RTCPeerConnection({ iceServers: [] });
  const tr = pc.addTransceiver('video', { direction: 'recvonly' });
  const caps = RTCRtpReceiver.getCapabilities('video').codecs;
  const h264 = caps.filter(c => c.mimeType === 'video/H264' && /packetization-mode=1/.test(c.sdpFmtpLine || '') &&
                                /profile-level-id=42e01f/.test(c.sdpFmtpLine || ''));
  if (!h264.length) throw new Error('this browser offers no H.264 Constrained Baseline for WebRTC');
  tr.setCodecPreferences([...h264, ...caps.filter(c => c.mimeType === 'video/rtx')]);
  const meta = pc.createDataChannel('meta');
  const frameCh = pc.createDataChannel('frame', { ordered: false, maxPacketLifeTime: 250 });
  const poseCh = pc.createDataChannel('pose', { ordered: false, maxRetransmits: 0 });
  await pc.setLocalDescription(await pc.createOffer());
  await gatheringDone(pc);
  const terms = await postJSON('/api/session', {
    type: 'offer', sdp: pc.localDescription.sdp, method: opts.method, width: opts.width, height: opts.height,
    display_hz: opts.display_hz,
  });
  await pc.setRemoteDescription({ type: 'answer', sdp: terms.sdp });
  state.session = terms.session_id;

  const canvas = $('#view');
  canvas.width = terms.width; canvas.height = terms.height;
  const display = makeDisplay(canvas, terms);
  const video = $('#video');
  video.srcObject = new MediaStream([tr.receiver.track]);
  video.play().catch(() => {});

  let origin = null;
  const metas = new Map();       // RTP timestamp (less the origin) -> frame metadata
  let framesWithoutMeta = 0, presented = 0;
  meta.binaryType = 'arraybuffer';
  let held = null;             // sas: a decoded atlas frame waiting for its patch slots, and its metadata
  let inflating = Promise.resolve();
  const inflate = buf => new Response(new Blob([buf]).stream().pipeThrough(new DecompressionStream('deflate'))).arrayBuffer();
  meta.onmessage = e => {
    if (typeof e.data !== 'string') {        // sas: a frame's patch slots, zlib-compressed, applied in order
      const data = e.data;
      inflating = inflating.then(() => inflate(data)).then(buf => {
        display.receive(parseSlotMessage(buf));
        if (held && display.ready(held.meta.id)) {
          display.upload(held.frame, held.meta);
          held.frame.close();
          held = null;
        }
      }).catch(fail);
      return;
    }
    const m = JSON.parse(e.data);
    if (m.type === 'origin') origin = m.rtp_origin;
    else if (m.type === 'error') fail(new Error(`server: ${m.text}`));
  };
  frameCh.onmessage = e => {
    const m = JSON.parse(e.data);
    if (m.origin !== null && m.origin !== undefined) origin = m.origin;
    metas.set(m.rtp, m);
    if (metas.size > 256) metas.delete(metas.keys().next().value);
  };
  const onVideoFrame = (now, md) => {
    presented++;
    const rel = origin === null || md.rtpTimestamp === undefined ? null : ((md.rtpTimestamp - origin) >>> 0);
    const m = rel === null ? undefined : metas.get(rel);
    if (m) {
      m.received_ms = md.receiveTime !== undefined ? performance.timeOrigin + md.receiveTime + offset : serverNow();
    }
    if (m && display.ready && !display.ready(m.id)) {
      // sas: the atlas frame came before its patch slots: keep it (a VideoFrame) until they arrive
      if (held) { held.frame.close(); framesWithoutMeta++; }
      held = { frame: new VideoFrame(video), meta: m };
    } else if (m) {
      display.upload(video, m);
    } else {
      framesWithoutMeta++;
    }
    video.requestVideoFrameCallback(onVideoFrame);
  };
  video.requestVideoFrameCallback(onVideoFrame);

  await Promise.all([opened(meta), opened(frameCh), opened(poseCh)]);
  // for tests of a misbehaving page: send raw text on one of the page's channels
  window.splitrender.send = (label, text) => ({ meta, frame: frameCh, pose: poseCh })[label].send(text);
  state.phase = 'streaming';
  const rows = [], uploads = [];
  let seq = 0, tick = 0, lastFeedback = -1;
  const t0 = serverNow();
  const duration = opts.trace === 'manual' ? opts.duration : Math.min(opts.duration, source.duration);
  const epochMs = terms.epoch_ms;

  await new Promise(resolve => {
    const frame = () => {
      const now = serverNow();
      const ts = (now - t0) / 1000;
      if (ts > duration || state.phase === 'failed') { resolve(); return; }
      const pose = source.poseAt(ts);
      if (poseCh.readyState === 'open') {
        poseCh.send(JSON.stringify({ type: 'pose', seq: seq++, t_us: Math.round(now * 1000), p: pose.p, q: pose.q }));
      }
      const c0 = performance.now();
      display.draw(pose);
      const f = display.frame;
      const row = {
        frame: rows.length, t_s: ts, tick, scene_t_s: (now - epochMs) / 1000, displayed_us: Math.round(now * 1000),
        update_frame_id: f ? f.id : -1, update_age_ms: f ? now - f.server_us / 1000 : null,
        motion_to_photon_ms: f ? now - f.pose_us / 1000 : null, client_ms: performance.now() - c0,
        rtp_timestamp: f ? f.rtp : null,
        px: pose.p[0], py: pose.p[1], pz: pose.p[2], qx: pose.q[0], qy: pose.q[1], qz: pose.q[2], qw: pose.q[3],
      };
      rows.push(row);
      if (opts.record_every > 0 && tick % opts.record_every === 0) {
        const px = display.readPixels();
        uploads.push(api(`/api/session/${terms.session_id}/image/${row.frame}`, { method: 'POST', body: px }));
      }
      if (f && f.id !== lastFeedback && poseCh.readyState === 'open') {
        lastFeedback = f.id;
        poseCh.send(JSON.stringify({ type: 'feedback', frame_id: f.id, displayed_us: row.displayed_us,
                                     received_us: Math.round(f.received_ms * 1000) }));
      }
      tick++;
      if (tick % 30 === 0) {
        $('#status').textContent = `session ${terms.session_id}  ${terms.method}  t=${ts.toFixed(1)} s  ` +
          `frame ${f ? f.id : '-'}  presented ${presented}  mtp ${row.motion_to_photon_ms ? row.motion_to_photon_ms.toFixed(0) : '-'} ms`;
      }
      requestAnimationFrame(frame);
    };
    requestAnimationFrame(frame);
  });
  if (state.phase === 'failed') { pc.close(); return; }
  state.phase = 'finishing';
  // statistics first: RTCP the page sent before them reaches the server before its bye does
  const stats = await inboundStats(pc);
  if (poseCh.readyState === 'open') poseCh.send(JSON.stringify({ type: 'bye' }));
  stats.framesPresented = presented;
  stats.framesWithoutMeta = framesWithoutMeta;
  await Promise.all(uploads);
  let saved = null;
  if (terms.recording !== false && opts.record_every >= 0) {
    try {
      saved = await postJSON(`/api/session/${terms.session_id}/recording`, {
        rows, stats, trace: opts.trace, duration_s: duration, record_every: opts.record_every,
        user_agent: navigator.userAgent, complete: true,
      });
    } catch (e) {
      saved = { error: e.message };
    }
  }
  pc.close();
  state.phase = 'done';
  state.result = { ok: true, session_id: terms.session_id, rows: rows.length, stats, saved };
  resolveDone(state.result);
}

async function main() {
  const info = await getJSON('/api/info');
  const form = $('#form');
  for (const m of info.methods) form.method.add(new Option(m, m));
  for (const t of [...info.traces, 'manual']) form.trace.add(new Option(t, t));
  $('#note').textContent = `scene ${info.scene}; methods the page draws: ` +
    info.methods.map(m => `${m} (${info.method_notes[m]})`).join('; ') +
    (info.network ? `; sessions shaped by ${info.network}` : '');
  const q = new URLSearchParams(location.search);
  const opts = {
    method: q.get('method') || info.methods[0], trace: q.get('trace') || 'walk',
    duration: Number(q.get('duration') || 10), width: Number(q.get('width') || 640), height: Number(q.get('height') || 360),
    record_every: Number(q.get('record_every') || 0), display_hz: Number(q.get('display_hz') || 60),
  };
  const start = o => { state.phase = 'starting'; run(o).catch(fail); };
  form.addEventListener('submit', e => {
    e.preventDefault();
    start({ ...opts, method: form.method.value, trace: form.trace.value, duration: Number(form.duration.value),
            width: Number(form.width.value), height: Number(form.height.value), record_every: Number(form.record_every.value) });
  });
  if (q.get('autostart') === '1') start(opts);
}

main().catch(fail);
