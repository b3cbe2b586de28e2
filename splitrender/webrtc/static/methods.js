// The page's method halves in WebGL 2: each keeps what arrived (the newest decoded frame as a texture, with the
// metadata the server sent for its RTP timestamp) and draws it for the current pose.
import { quatToMat3 } from './pose.js';

const VERT = `#version 300 es
void main() {
  vec2 p = vec2(float((gl_VertexID << 1) & 2), float(gl_VertexID & 2));
  gl_Position = vec4(p * 2.0 - 1.0, 0.0, 1.0);
}`;

// video: the frame as it came.  atw: each display pixel looks up the reference frame through a homography H
// (display pixel -> reference pixel, both top-left origin), as splitrender's own atw client does.
const FRAG = `#version 300 es
precision highp float;
uniform sampler2D u_ref;
uniform vec2 u_ref_size;
uniform vec2 u_out_size;
uniform mat3 u_H;
uniform int u_fill_edge;
out vec4 f_color;
void main() {
  vec2 px = vec2(gl_FragCoord.x, u_out_size.y - gl_FragCoord.y);
  vec3 h = u_H * vec3(px, 1.0);
  if (h.z <= 1e-6) { f_color = vec4(0.0, 0.0, 0.0, 1.0); return; }
  vec2 q = h.xy / h.z;
  bool inside = all(greaterThanEqual(q, vec2(0.0))) && all(lessThanEqual(q, u_ref_size));
  if (!inside && u_fill_edge == 0) { f_color = vec4(0.0, 0.0, 0.0, 1.0); return; }
  vec2 uv = clamp(q, vec2(0.5), u_ref_size - 0.5) / u_ref_size;
  f_color = vec4(texture(u_ref, uv).rgb, 1.0);
}`;

function compile(gl, type, src) {
  const s = gl.createShader(type);
  gl.shaderSource(s, src);
  gl.compileShader(s);
  if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error('shader: ' + gl.getShaderInfoLog(s));
  return s;
}

function program(gl, vs, fs) {
  const p = gl.createProgram();
  gl.attachShader(p, compile(gl, gl.VERTEX_SHADER, vs));
  gl.attachShader(p, compile(gl, gl.FRAGMENT_SHADER, fs));
  gl.linkProgram(p);
  if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error('program: ' + gl.getProgramInfoLog(p));
  return p;
}

// a 2D texture clamped to its edges, with one filter for minification and magnification
function texture(gl, filter) {
  const tex = gl.createTexture();
  gl.bindTexture(gl.TEXTURE_2D, tex);
  for (const [k, v] of [[gl.TEXTURE_MIN_FILTER, filter], [gl.TEXTURE_MAG_FILTER, filter],
                        [gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE], [gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE]]) {
    gl.texParameteri(gl.TEXTURE_2D, k, v);
  }
  return tex;
}

// 3x3 helpers, row-major arrays of rows
const mul = (a, b) => a.map((r, i) => [0, 1, 2].map(j => r[0] * b[0][j] + r[1] * b[1][j] + r[2] * b[2][j]));
const transpose = a => [0, 1, 2].map(i => [a[0][i], a[1][i], a[2][i]]);
function inverse(m) {
  const [[a, b, c], [d, e, f], [g, h, i]] = m;
  const A = e * i - f * h, B = -(d * i - f * g), C = d * h - e * g;
  const det = a * A + b * B + c * C;
  return [[A / det, -(b * i - c * h) / det, (b * f - c * e) / det],
          [B / det, (a * i - c * g) / det, -(a * f - c * d) / det],
          [C / det, -(a * h - b * g) / det, (a * e - b * d) / det]];
}

// camera-space direction -> homogeneous top-left pixel (the server's pixel_projection)
function pixelProjection(width, height, fovYDeg) {
  const f = height / 2 / Math.tan(fovYDeg * Math.PI / 360);
  return [[f, 0, -width / 2], [0, -f, -height / 2], [0, 0, -1]];
}

export function rotationHomography(ref, refQ, cur, curQ) {
  const pr = pixelProjection(ref.width, ref.height, ref.fov);
  const pc = pixelProjection(cur.width, cur.height, cur.fov);
  return mul(mul(mul(pr, transpose(quatToMat3(refQ))), quatToMat3(curQ)), inverse(pc));
}

export class Display {
  // terms: the server's answer (method, width, height, stream size, fov, ref_fov_y_deg for atw)
  constructor(canvas, terms) {
    this.terms = terms;
    const gl = canvas.getContext('webgl2', { antialias: false, alpha: false, preserveDrawingBuffer: false });
    if (!gl) throw new Error('this browser has no WebGL 2');
    this.gl = gl;
    this.prog = program(gl, VERT, FRAG);
    this.vao = gl.createVertexArray();
    this.tex = texture(gl, gl.LINEAR);
    this.frame = null;       // the metadata of the frame in the texture
  }

  // a decoded frame and its metadata (from requestVideoFrameCallback)
  upload(video, meta) {
    const gl = this.gl;
    gl.bindTexture(gl.TEXTURE_2D, this.tex);
    gl.pixelStorei(gl.UNPACK_FLIP_Y_WEBGL, false);
    gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGB, gl.RGB, gl.UNSIGNED_BYTE, video);
    this.frame = meta;
  }

  draw(pose) {
    const gl = this.gl, t = this.terms;
    gl.viewport(0, 0, t.width, t.height);
    gl.clearColor(0, 0, 0, 1);
    gl.clear(gl.COLOR_BUFFER_BIT);
    if (!this.frame) return;
    let H = [[t.stream_width / t.width, 0, 0], [0, t.stream_height / t.height, 0], [0, 0, 1]];
    let fill = 1;
    if (t.method === 'atw') {
      H = rotationHomography({ width: t.stream_width, height: t.stream_height, fov: t.ref_fov_y_deg }, this.frame.q,
                             { width: t.width, height: t.height, fov: t.fov_y_deg }, pose.q);
      fill = t.fill === 'black' ? 0 : 1;
    }
    gl.useProgram(this.prog);
    gl.activeTexture(gl.TEXTURE0);
    gl.bindTexture(gl.TEXTURE_2D, this.tex);
    gl.uniform1i(gl.getUniformLocation(this.prog, 'u_ref'), 0);
    gl.uniform2f(gl.getUniformLocation(this.prog, 'u_ref_size'), t.stream_width, t.stream_height);
    gl.uniform2f(gl.getUniformLocation(this.prog, 'u_out_size'), t.width, t.height);
    gl.uniform1i(gl.getUniformLocation(this.prog, 'u_fill_edge'), fill);
    // GLSL matrices are column-major: pass the transpose of the row-major H
    gl.uniformMatrix3fv(gl.getUniformLocation(this.prog, 'u_H'), false, transpose(H).flat());
    gl.bindVertexArray(this.vao);
    gl.drawArrays(gl.TRIANGLES, 0, 3);
  }

  readPixels() {
    const gl = this.gl, t = this.terms;
    const buf = new Uint8Array(t.width * t.height * 4);
    gl.readPixels(0, 0, t.width, t.height, gl.RGBA, gl.UNSIGNED_BYTE, buf);
    return buf;
  }
}

// sas: the atlas is the video texture; the PVS patches are vertex slots (3 triangles each) the server sends on
// the meta channel when they change; object transforms come with them.  The SAS client's shaders, in GLSL ES.
const SAS_VERT = `#version 300 es
precision highp float;
precision highp sampler2D;
uniform sampler2D u_models;     // RGBA32F, 4 x n_objects: row j of object i's matrix at texel (j, i)
uniform mat4 u_view;
uniform mat4 u_proj;
in vec3 in_position;
in vec2 in_atlas_uv;
in float in_object;
in vec4 in_clamp;
out vec2 v_uv;
flat out vec4 v_clamp;
void main() {
  int o = int(in_object + 0.5);
  mat4 m = transpose(mat4(texelFetch(u_models, ivec2(0, o), 0), texelFetch(u_models, ivec2(1, o), 0),
                          texelFetch(u_models, ivec2(2, o), 0), texelFetch(u_models, ivec2(3, o), 0)));
  v_uv = in_atlas_uv;
  v_clamp = in_clamp;
  gl_Position = u_proj * u_view * m * vec4(in_position, 1.0);
}`;

const SAS_FRAG = `#version 300 es
precision highp float;
uniform sampler2D u_atlas;
in vec2 v_uv;
flat in vec4 v_clamp;
out vec4 f_color;
vec4 catmull_rom(float t) {
  float t2 = t * t, t3 = t2 * t;
  return vec4(-0.5 * t3 + t2 - 0.5 * t, 1.5 * t3 - 2.5 * t2 + 1.0, -1.5 * t3 + 2.0 * t2 + 0.5 * t, 0.5 * t3 - 0.5 * t2);
}
void main() {
  vec2 uv = clamp(v_uv, v_clamp.xy, v_clamp.zw);
  vec2 size = vec2(textureSize(u_atlas, 0));
  vec2 p = uv * size - 0.5;
  vec2 i0 = floor(p);
  vec2 f = p - i0;
  ivec2 lo = ivec2(floor(v_clamp.xy * size)), hi = ivec2(floor(v_clamp.zw * size));
  vec4 wx = catmull_rom(f.x), wy = catmull_rom(f.y);
  vec3 acc = vec3(0.0);
  for (int j = 0; j < 4; ++j) {
    vec3 row = vec3(0.0);
    for (int i = 0; i < 4; ++i)
      row += wx[i] * texelFetch(u_atlas, clamp(ivec2(i0) + ivec2(i - 1, j - 1), lo, hi), 0).rgb;
    acc += wy[j] * row;
  }
  f_color = vec4(clamp(acc, 0.0, 1.0), 1.0);
}`;

const FLOATS_PER_SLOT = 90;

// one slot message (see splitrender/methods/sas/page.py)
export function parseSlotMessage(buf) {
  const u = new Uint32Array(buf, 0, 8);
  const magic = String.fromCharCode(...new Uint8Array(buf, 0, 4));
  if (magic !== 'SRSA') throw new Error(`slot message: magic ${magic}`);
  const [frameId, part, last, high, n, nXf] = [u[1], u[2], u[3], u[4], u[5], u[6]];
  let o = 32;
  const slots = new Uint32Array(buf, o, n); o += 4 * n;
  const rows = new Float32Array(buf, o, n * FLOATS_PER_SLOT); o += 4 * n * FLOATS_PER_SLOT;
  const objects = new Uint32Array(buf, o, nXf); o += 4 * nXf;
  const transforms = new Float32Array(buf, o, nXf * 16); o += 64 * nXf;
  if (o !== buf.byteLength) throw new Error(`slot message: ${buf.byteLength} bytes, its counts say ${o}`);
  return { frameId, part, last: !!last, high, slots, rows, objects, transforms };
}

function viewMatrix(pose) {          // world -> camera, row-major
  const r = quatToMat3(pose.q), p = pose.p;
  const m = [[0, 0, 0, 0], [0, 0, 0, 0], [0, 0, 0, 0], [0, 0, 0, 1]];
  for (let i = 0; i < 3; i++) {
    for (let j = 0; j < 3; j++) m[i][j] = r[j][i];
    m[i][3] = -(r[0][i] * p[0] + r[1][i] * p[1] + r[2][i] * p[2]);
  }
  return m;
}

function projection(width, height, fovYDeg, near = 0.05, far = 100.0) {
  const f = 1 / Math.tan(fovYDeg * Math.PI / 360);
  return [[f * height / width, 0, 0, 0], [0, f, 0, 0], [0, 0, (far + near) / (near - far), 2 * far * near / (near - far)],
          [0, 0, -1, 0]];
}

const colMajor4 = m => [0, 1, 2, 3].flatMap(j => [m[0][j], m[1][j], m[2][j], m[3][j]]);

export class SasDisplay {
  constructor(canvas, terms) {
    this.terms = terms;
    const gl = canvas.getContext('webgl2', { antialias: false, alpha: false, depth: true });
    if (!gl) throw new Error('this browser has no WebGL 2');
    this.gl = gl;
    this.prog = program(gl, SAS_VERT, SAS_FRAG);
    this.vao = gl.createVertexArray();
    this.vbo = gl.createBuffer();
    gl.bindVertexArray(this.vao);
    gl.bindBuffer(gl.ARRAY_BUFFER, this.vbo);
    let off = 0;
    for (const [name, n] of [['in_position', 3], ['in_atlas_uv', 2], ['in_object', 1], ['in_clamp', 4]]) {
      const loc = gl.getAttribLocation(this.prog, name);
      gl.enableVertexAttribArray(loc);
      gl.vertexAttribPointer(loc, n, gl.FLOAT, false, 40, off);
      off += 4 * n;
    }
    this.atlas = texture(gl, gl.NEAREST);      // read with texelFetch (the Catmull-Rom taps)
    this.models = texture(gl, gl.NEAREST);     // RGBA32F: not filterable
    this.nObj = Math.max(1, terms.n_objects);
    this.xf = new Float32Array(this.nObj * 16);
    for (let i = 0; i < this.nObj; i++) for (let k = 0; k < 4; k++) this.xf[i * 16 + k * 5] = 1;
    this.rows = new Float32Array(64 * FLOATS_PER_SLOT);
    this.high = 0;
    this.dirty = true;
    this.pending = [];          // slot messages not yet applied, in order
    this.complete = -1;         // the newest frame whose slot messages have all arrived
    this.frame = null;
  }

  // a slot message from the meta channel (applied with its atlas frame)
  receive(msg) {
    this.pending.push(msg);
    if (msg.last) this.complete = msg.frameId;
  }

  ready(frameId) { return frameId <= this.complete; }

  _apply(upTo) {
    while (this.pending.length && this.pending[0].frameId <= upTo) {
      const m = this.pending.shift();
      const need = Math.max(m.high, ...Array.from(m.slots, s => s + 1), 0) * FLOATS_PER_SLOT;
      if (need > this.rows.length) {
        const grown = new Float32Array(Math.max(need, 2 * this.rows.length));
        grown.set(this.rows);
        this.rows = grown;
      }
      for (let k = 0; k < m.slots.length; k++) {
        this.rows.set(m.rows.subarray(k * FLOATS_PER_SLOT, (k + 1) * FLOATS_PER_SLOT), m.slots[k] * FLOATS_PER_SLOT);
      }
      for (let k = 0; k < m.objects.length; k++) {
        if (m.objects[k] < this.nObj) this.xf.set(m.transforms.subarray(k * 16, k * 16 + 16), m.objects[k] * 16);
      }
      if (m.last) this.high = m.high;
      this.dirty = true;
    }
  }

  upload(video, meta) {
    this._apply(meta.id);
    const gl = this.gl;
    gl.bindTexture(gl.TEXTURE_2D, this.atlas);
    gl.pixelStorei(gl.UNPACK_FLIP_Y_WEBGL, false);
    gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGB, gl.RGB, gl.UNSIGNED_BYTE, video);
    this.frame = meta;
  }

  draw(pose) {
    const gl = this.gl, t = this.terms, sky = t.sky;
    gl.viewport(0, 0, t.width, t.height);
    gl.clearColor(sky[0], sky[1], sky[2], 1);
    gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    if (!this.frame) { gl.clearColor(0, 0, 0, 1); gl.clear(gl.COLOR_BUFFER_BIT); return; }
    if (this.dirty) {
      gl.bindBuffer(gl.ARRAY_BUFFER, this.vbo);
      gl.bufferData(gl.ARRAY_BUFFER, this.rows.subarray(0, this.high * FLOATS_PER_SLOT), gl.DYNAMIC_DRAW);
      gl.bindTexture(gl.TEXTURE_2D, this.models);
      gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA32F, 4, this.nObj, 0, gl.RGBA, gl.FLOAT, this.xf);
      this.dirty = false;
    }
    gl.enable(gl.DEPTH_TEST);
    gl.disable(gl.CULL_FACE);
    gl.useProgram(this.prog);
    gl.activeTexture(gl.TEXTURE0);
    gl.bindTexture(gl.TEXTURE_2D, this.atlas);
    gl.uniform1i(gl.getUniformLocation(this.prog, 'u_atlas'), 0);
    gl.activeTexture(gl.TEXTURE1);
    gl.bindTexture(gl.TEXTURE_2D, this.models);
    gl.uniform1i(gl.getUniformLocation(this.prog, 'u_models'), 1);
    gl.uniformMatrix4fv(gl.getUniformLocation(this.prog, 'u_view'), false, colMajor4(viewMatrix(pose)));
    gl.uniformMatrix4fv(gl.getUniformLocation(this.prog, 'u_proj'), false,
                        colMajor4(projection(t.width, t.height, t.fov_y_deg)));
    gl.bindVertexArray(this.vao);
    gl.drawArrays(gl.TRIANGLES, 0, this.high * 9);
  }

  readPixels() { return Display.prototype.readPixels.call(this); }
}

export function makeDisplay(canvas, terms) {
  return terms.method === 'sas' ? new SasDisplay(canvas, terms) : new Display(canvas, terms);
}
