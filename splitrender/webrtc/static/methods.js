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
    this.tex = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D, this.tex);
    for (const [k, v] of [[gl.TEXTURE_MIN_FILTER, gl.LINEAR], [gl.TEXTURE_MAG_FILTER, gl.LINEAR],
                          [gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE], [gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE]]) {
      gl.texParameteri(gl.TEXTURE_2D, k, v);
    }
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
