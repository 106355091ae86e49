#pragma once
/// \file
/// GLSL ES 3.00 sources of the scene renderer (internal to eyesim_render).

namespace eyesim::render::scene_shaders {

/// Material ids shared by the C++ side and the fragment shader.
enum Material : int { kFundus = 0, kMembrane = 1, kMetal = 2, kDot = 3, kLightPipe = 4 };

/// Shadow pass: positions through the light's view-projection; fragments outside the eye are dropped.
inline constexpr const char* kShadowVertex = R"(#version 300 es
layout(location = 0) in vec3 a_pos;
uniform mat4 u_light_view_proj;
out vec3 v_pos;
void main() { v_pos = a_pos; gl_Position = u_light_view_proj * vec4(a_pos, 1.0); }
)";

inline constexpr const char* kShadowFragment = R"(#version 300 es
precision highp float;
in vec3 v_pos;
uniform float u_clip_radius;
void main() { if (dot(v_pos, v_pos) > u_clip_radius * u_clip_radius) discard; }
)";

/// Fundus bake: a full-screen triangle; each texel gets the procedural albedo of its eye-frame (x, y), stored
/// sqrt-encoded so that the dark reds keep their precision in 8 bits. Done once at start-up.
inline constexpr const char* kBakeVertex = R"(#version 300 es
out vec2 v_uv;
void main() {
    vec2 p = vec2(float((gl_VertexID & 1) * 4 - 1), float((gl_VertexID & 2) * 2 - 1));
    v_uv = p * 0.5 + 0.5;
    gl_Position = vec4(p, 0.0, 1.0);
}
)";

inline constexpr const char* kBakeFragment = R"(#version 300 es
precision highp float;
in vec2 v_uv;
out vec4 o_color;
uniform float u_fundus_half_mm;
// Procedural fundus albedo over the eye-frame x, y plane (mm): orange-red choroid, vessels from the optic disc
// arching around the macula, a pale disc, a darker macula.
vec3 fundus_albedo(vec2 q) {
    vec3 base = vec3(0.75, 0.13, 0.03);
    // Choroidal mottling (smooth, deterministic).
    float mottle = 0.5 + 0.25 * sin(q.x * 5.3 + sin(q.y * 3.1)) * sin(q.y * 4.7 + sin(q.x * 2.3));
    base *= 0.88 + 0.24 * mottle;
    // Macula: darker towards the posterior pole's centre.
    float rm = length(q);
    base *= mix(0.62, 1.0, smoothstep(0.3, 2.2, rm));
    // Vessels: branches leave the disc and bend around the macula.
    vec2 disc = vec2(3.6, 0.4);
    vec2 d = q - disc;
    float r = length(d);
    float a = atan(d.y, d.x);
    float vessel = 0.0;
    for (int k = 0; k < 8; ++k) {
        float fk = float(k);
        float side = (k % 2 == 0) ? 1.0 : -1.0;
        float a0 = (k < 4) ? 3.14159 - side * (0.45 + 0.12 * fk) : side * (0.9 + 0.25 * (fk - 4.0));
        float bend = (k < 4) ? side * (0.10 + 0.02 * fk) : side * 0.05;
        float target = a0 + bend * r;
        float da = a - target;
        da = da - 6.28318 * floor((da + 3.14159) / 6.28318);
        float dist = abs(da) * r;
        float len = (k < 4) ? 11.0 : 6.0;
        float width = mix(0.16, 0.04, clamp(r / len, 0.0, 1.0)) * ((k < 2) ? 1.2 : 1.0);
        float v = (1.0 - smoothstep(width * 0.5, width, dist)) * (1.0 - smoothstep(len * 0.8, len, r));
        vessel = max(vessel, v);
    }
    base = mix(base, vec3(0.34, 0.02, 0.02), 0.85 * vessel * smoothstep(0.6, 1.0, r));
    // Optic disc with a pale cup.
    float disc_mask = 1.0 - smoothstep(0.7, 0.85, r);
    base = mix(base, vec3(0.95, 0.72, 0.48), disc_mask);
    base = mix(base, vec3(1.0, 0.9, 0.75), 1.0 - smoothstep(0.2, 0.35, r));
    return base;
}

void main() { o_color = vec4(sqrt(fundus_albedo((v_uv * 2.0 - 1.0) * u_fundus_half_mm)), 1.0); }
)";

/// Scene pass: eye-frame positions and normals through the view's view-projection.
inline constexpr const char* kSceneVertex = R"(#version 300 es
layout(location = 0) in vec3 a_pos;
layout(location = 1) in vec3 a_nrm;
uniform mat4 u_view_proj;
uniform float u_scale;   // the eye sphere is a unit sphere scaled here; 1 for everything else
out vec3 v_pos;
out vec3 v_nrm;
void main() {
    v_pos = a_pos * u_scale;
    v_nrm = a_nrm;
    gl_Position = u_view_proj * vec4(v_pos, 1.0);
}
)";

/// Scene pass shading: procedural fundus, membrane, metal, dots; the light pipe's spot with two shadow maps
/// (opaque instruments, and the translucent membrane which blocks only part of the light); round field stop.
inline constexpr const char* kSceneFragment = R"(#version 300 es
precision highp float;
precision highp sampler2DShadow;
in vec3 v_pos;
in vec3 v_nrm;
out vec4 o_color;

uniform int u_material;
uniform vec4 u_color;
uniform vec3 u_cam_pos;
uniform float u_clip_radius;      // fragments farther than this from the eye centre are not drawn (< 0: off)
uniform float u_eye_radius;
uniform float u_ambient;
uniform float u_coaxial;
uniform int u_has_spot;
uniform vec3 u_spot_pos;
uniform vec3 u_spot_dir;
uniform float u_spot_cos_outer;
uniform float u_spot_cos_inner;
uniform float u_spot_intensity;
uniform float u_spot_falloff_mm;
uniform mat4 u_light_view_proj;
uniform sampler2DShadow u_shadow_opaque;
uniform sampler2DShadow u_shadow_tissue;
uniform float u_tissue_shadow;    // fraction of light the membrane blocks where it shadows
uniform float u_shadow_texel;
uniform sampler2D u_fundus;      // baked fundus albedo over the eye-frame x, y plane
uniform float u_fundus_half_mm;
uniform vec2 u_centre_px;
uniform float u_stop_radius_px;   // <= 0: no field stop

// Percentage-closer filtering of one shadow map: 2x2 taps half a texel apart, each a bilinear hardware comparison
// (a 3x3 texel footprint); 1 = fully lit.
float lit_fraction(sampler2DShadow map, vec3 p) {
    vec4 c = u_light_view_proj * vec4(p, 1.0);
    if (c.w <= 1e-4) return 1.0;
    vec3 s = c.xyz / c.w * 0.5 + 0.5;
    if (s.x < 0.0 || s.x > 1.0 || s.y < 0.0 || s.y > 1.0 || s.z > 1.0) return 1.0;
    float h = 0.5 * u_shadow_texel;
    return 0.25 * (textureLod(map, vec3(s.xy + vec2(-h, -h), s.z), 0.0) + textureLod(map, vec3(s.xy + vec2(h, -h), s.z), 0.0) +
                   textureLod(map, vec3(s.xy + vec2(-h, h), s.z), 0.0) + textureLod(map, vec3(s.xy + vec2(h, h), s.z), 0.0));
}

// Fundus albedo from the baked texture (sqrt-encoded), darker towards the periphery.
vec3 fundus_albedo(vec3 p) {
    vec3 t = texture(u_fundus, p.xy / (2.0 * u_fundus_half_mm) + 0.5).rgb;
    float pole = clamp(-p.z / u_eye_radius, 0.0, 1.0);
    return t * t * mix(0.35, 1.0, smoothstep(0.45, 0.95, pole));
}

void main() {
    if (u_clip_radius > 0.0 && dot(v_pos, v_pos) > u_clip_radius * u_clip_radius) discard;
    vec3 p = v_pos;
    vec3 v = normalize(u_cam_pos - p);
    vec3 n = normalize(v_nrm);
    if (dot(n, v) < 0.0) n = -n;  // two-sided

    vec3 albedo = u_color.rgb;
    float alpha = 1.0;
    if (u_material == 0) albedo = fundus_albedo(p);
    if (u_material == 1) alpha = u_color.a;

    vec3 rgb;
    if (u_material == 3) {
        rgb = u_color.rgb;
    } else {
        // Microscope coaxial light from the viewer's side and a little ambient.
        float coax = max(dot(n, vec3(0.0, 0.0, 1.0)), 0.0);
        vec3 diffuse_light = vec3(u_ambient + u_coaxial * coax);
        vec3 spec_light = vec3(0.0);
        float shininess = (u_material == 2 || u_material == 4) ? 40.0 : 18.0;
        float spec_strength = (u_material == 2 || u_material == 4) ? 0.9 : ((u_material == 1) ? 0.25 : 0.06);
        {
            // The microscope lamp's mirror image: weak on tissue, a bright stripe along polished metal.
            vec3 h = normalize(vec3(0.0, 0.0, 1.0) + v);
            bool metal = u_material == 2 || u_material == 4;
            spec_light += vec3((metal ? 6.0 : 1.0) * u_coaxial * pow(max(dot(n, h), 0.0), metal ? 60.0 : shininess));
        }
        if (u_has_spot == 1) {
            vec3 l = u_spot_pos - p;
            float dist = length(l);
            l /= max(dist, 1e-4);
            float cone = smoothstep(u_spot_cos_outer, u_spot_cos_inner, dot(-l, u_spot_dir));
            float fall = 1.0 / (1.0 + (dist / u_spot_falloff_mm) * (dist / u_spot_falloff_mm));
            float lit = 1.0;
            if (cone > 0.0) {
                lit = lit_fraction(u_shadow_opaque, p + n * 0.02);
                if (u_material != 1 && u_tissue_shadow > 0.0)
                    lit *= 1.0 - u_tissue_shadow * (1.0 - lit_fraction(u_shadow_tissue, p + n * 0.02));
            }
            float e = u_spot_intensity * cone * fall * lit;
            float ndl = dot(n, l);
            if (u_material == 1) ndl = abs(ndl);  // thin membrane: lit through from either side
            diffuse_light += vec3(1.0, 0.97, 0.9) * e * max(ndl, 0.0);
            vec3 h = normalize(l + v);
            spec_light += vec3(1.0, 0.97, 0.9) * e * pow(max(dot(n, h), 0.0), shininess) * step(0.0, ndl);
        }
        rgb = albedo * diffuse_light + spec_strength * spec_light;
        if (u_material == 2 || u_material == 4) {
            // Metal mirrors its surroundings: the lit orange fundus below, the dark front of the eye above.
            vec3 refl = reflect(-v, n);
            float fundus_seen = smoothstep(0.2, -0.7, refl.z);
            float scene_light = u_ambient + u_coaxial + (u_has_spot == 1 ? 0.35 : 0.0);
            rgb += albedo * 0.4 * scene_light * fundus_seen * vec3(0.85, 0.45, 0.3);
            rgb += albedo * 0.08 * (1.0 - abs(dot(n, v)));  // rim sheen
        }
        if (u_material == 4 && u_has_spot == 1) {
            // The light pipe's emitting end face glows.
            float along = dot(p - u_spot_pos, u_spot_dir);
            rgb = mix(rgb, vec3(1.0, 0.98, 0.9), smoothstep(-0.12, -0.02, along));
        }
    }
    rgb = pow(clamp(rgb, 0.0, 1.0), vec3(1.0 / 2.2));
    if (u_stop_radius_px > 0.0) {
        float rs = length(gl_FragCoord.xy - u_centre_px);
        rgb *= 1.0 - smoothstep(u_stop_radius_px - 3.0, u_stop_radius_px, rs);
    }
    o_color = vec4(rgb, alpha);
}
)";

}  // namespace eyesim::render::scene_shaders
