#version 430
// Clears every attachment of the G-buffer to its background value in one pass
// (integer attachments cannot be cleared with a float colour).
uniform vec3 u_sky;
layout(location = 0) out vec4 f_color;
layout(location = 1) out vec4 f_normal;
layout(location = 2) out uvec2 f_ids;
layout(location = 3) out float f_depth;
void main() {
    f_color = vec4(u_sky, 1.0);
    f_normal = vec4(0.0);
    f_ids = uvec2(0u);
    f_depth = 1.0 / 0.0;
}
