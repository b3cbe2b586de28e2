#version 430
// Never runs (rasteriser discard); the program needs a fragment stage to link on Mesa.
out vec4 f_color;
void main() { f_color = vec4(0.0); }
