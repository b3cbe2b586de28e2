#version 430
// DDGI probe capture (splitrender/gi/ddgi.py): one instance per (probe, cube face) an object reaches.
// Each instance is transformed into its face's 90-degree frustum, clipped to it with four clip
// distances, and mapped into its F x F tile of the G-buffer atlas: one draw per object for
// every probe face, instead of one per face with its own viewport.
in vec3 in_position;
in vec3 in_normal;
in vec2 in_uv;
in vec4 in_tangent;          // xyz object space, w handedness
in vec3 i_eye;               // per instance: the probe
in int i_pf;                 // per instance: probe * 6 + face
uniform mat4 u_model;
uniform mat3 u_normal_matrix;
uniform mat4 u_proj;
uniform mat3 u_face_rot[6];  // world to view rotation of each cube face
uniform int u_face_res;
uniform int u_cols;          // probe tiles per atlas row
uniform vec2 u_atlas;        // atlas size, pixels
out vec3 v_world;
out vec3 v_normal;
out vec2 v_uv;
out vec4 v_tangent;
out float v_view_depth;
flat out vec3 v_eye;
void main() {
    int p = i_pf / 6;
    int f = i_pf - 6 * p;
    vec4 w = u_model * vec4(in_position, 1.0);
    v_world = w.xyz;
    v_normal = u_normal_matrix * in_normal;
    v_uv = in_uv;
    v_tangent = vec4(mat3(u_model) * in_tangent.xyz, in_tangent.w);
    v_eye = i_eye;
    vec3 vp = u_face_rot[f] * (w.xyz - i_eye);
    v_view_depth = -vp.z;
    vec4 c = u_proj * vec4(vp, 1.0);
    gl_ClipDistance[0] = c.w + c.x;
    gl_ClipDistance[1] = c.w - c.x;
    gl_ClipDistance[2] = c.w + c.y;
    gl_ClipDistance[3] = c.w - c.y;
    float F = float(u_face_res);
    vec2 tile = vec2(float((p % u_cols) * 6 * u_face_res + f * u_face_res), float((p / u_cols) * u_face_res));
    vec2 scale = vec2(F) / u_atlas;
    vec2 centre = (tile + 0.5 * F) / u_atlas * 2.0 - 1.0;
    gl_Position = vec4(c.xy * scale + centre * c.w, c.z, c.w);
}
