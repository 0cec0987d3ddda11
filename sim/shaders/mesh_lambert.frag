#version 330 core
// A cheaper fragment shader for pyrender's meshes (sim.render): the diffuse term of pyrender's
// metallic-roughness BRDF only (Lambert, with the dielectric's 4% Fresnel loss), without its
// specular lobe, shadows or image-based lighting. Same structs, uniforms and inputs as
// pyrender 0.1.45's shaders/mesh.frag (MIT licence), from which the declarations are copied.
// On a CPU rasteriser (Mesa llvmpipe) the specular microfacet terms per light were most of a
// frame's cost.
///////////////////////////////////////////////////////////////////////////////
// Structs
///////////////////////////////////////////////////////////////////////////////

struct SpotLight {
    vec3 color;
    float intensity;
    float range;
    vec3 position;
    vec3 direction;
    float light_angle_scale;
    float light_angle_offset;

    #ifdef SPOT_LIGHT_SHADOWS
    sampler2D shadow_map;
    mat4 light_matrix;
    #endif
};

struct DirectionalLight {
    vec3 color;
    float intensity;
    vec3 direction;

    #ifdef DIRECTIONAL_LIGHT_SHADOWS
    sampler2D shadow_map;
    mat4 light_matrix;
    #endif
};

struct PointLight {
    vec3 color;
    float intensity;
    float range;
    vec3 position;

    #ifdef POINT_LIGHT_SHADOWS
    samplerCube shadow_map;
    #endif
};

struct Material {
    vec3 emissive_factor;

#ifdef USE_METALLIC_MATERIAL
    vec4 base_color_factor;
    float metallic_factor;
    float roughness_factor;
#endif

#ifdef USE_GLOSSY_MATERIAL
    vec4 diffuse_factor;
    vec3 specular_factor;
    float glossiness_factor;
#endif

#ifdef HAS_NORMAL_TEX
    sampler2D normal_texture;
#endif
#ifdef HAS_OCCLUSION_TEX
    sampler2D occlusion_texture;
#endif
#ifdef HAS_EMISSIVE_TEX
    sampler2D emissive_texture;
#endif
#ifdef HAS_BASE_COLOR_TEX
    sampler2D base_color_texture;
#endif
#ifdef HAS_METALLIC_ROUGHNESS_TEX
    sampler2D metallic_roughness_texture;
#endif
#ifdef HAS_DIFFUSE_TEX
    sampler2D diffuse_texture;
#endif
#ifdef HAS_SPECULAR_GLOSSINESS_TEX
    sampler2D specular_glossiness;
#endif
};

struct PBRInfo {
    float nl;
    float nv;
    float nh;
    float lh;
    float vh;
    float roughness;
    float metallic;
    vec3 f0;
    vec3 c_diff;
};

///////////////////////////////////////////////////////////////////////////////
// Uniforms
///////////////////////////////////////////////////////////////////////////////
uniform Material material;
uniform PointLight point_lights[MAX_POINT_LIGHTS];
uniform int n_point_lights;
uniform DirectionalLight directional_lights[MAX_DIRECTIONAL_LIGHTS];
uniform int n_directional_lights;
uniform SpotLight spot_lights[MAX_SPOT_LIGHTS];
uniform int n_spot_lights;
uniform vec3 cam_pos;
uniform vec3 ambient_light;

#ifdef USE_IBL
uniform samplerCube diffuse_env;
uniform samplerCube specular_env;
#endif

// Light loop bounds: compile-time constants when sim.render knows the scene's light counts
// (llvmpipe unrolls them into direct uniform reads; a uniform bound makes every read a per-lane
// gather), else pyrender's uniforms. Same arithmetic, same order, same pixels.
#ifdef N_DIRECTIONAL_LIGHTS
#define N_DIRECTIONAL N_DIRECTIONAL_LIGHTS
#define N_SPOT N_SPOT_LIGHTS
#define N_POINT N_POINT_LIGHTS
#else
#define N_DIRECTIONAL n_directional_lights
#define N_SPOT n_spot_lights
#define N_POINT n_point_lights
#endif

///////////////////////////////////////////////////////////////////////////////
// Inputs
///////////////////////////////////////////////////////////////////////////////

in vec3 frag_position;
#ifdef NORMAL_LOC
in vec3 frag_normal;
#endif
#ifdef HAS_NORMAL_TEX
#ifdef TANGENT_LOC
#ifdef NORMAL_LOC
in mat3 tbn;
#endif
#endif
#endif
#ifdef TEXCOORD_0_LOC
in vec2 uv_0;
#endif
#ifdef TEXCOORD_1_LOC
in vec2 uv_1;
#endif
#ifdef COLOR_0_LOC
in vec4 color_multiplier;
#endif

///////////////////////////////////////////////////////////////////////////////
// OUTPUTS
///////////////////////////////////////////////////////////////////////////////

out vec4 frag_color;

///////////////////////////////////////////////////////////////////////////////
// Constants
///////////////////////////////////////////////////////////////////////////////
const float PI = 3.141592653589793;
const float min_roughness = 0.04;

///////////////////////////////////////////////////////////////////////////////
// Utility Functions
///////////////////////////////////////////////////////////////////////////////
vec4 srgb_to_linear(vec4 srgb)
{
#ifndef SRGB_CORRECTED
    // Fast Approximation
    //vec3 linOut = pow(srgbIn.xyz,vec3(2.2));
    //
    vec3 b_less = step(vec3(0.04045),srgb.xyz);
    vec3 lin_out = mix( srgb.xyz/vec3(12.92), pow((srgb.xyz+vec3(0.055))/vec3(1.055),vec3(2.4)), b_less );
    return vec4(lin_out, srgb.w);
#else
    return srgb;
#endif
}

// Normal computation
vec3 get_normal()
{
#ifdef HAS_NORMAL_TEX

#ifndef HAS_TANGENTS
    vec3 pos_dx = dFdx(frag_position);
    vec3 pos_dy = dFdy(frag_position);
    vec3 tex_dx = dFdx(vec3(uv_0, 0.0));
    vec3 tex_dy = dFdy(vec3(uv_0, 0.0));
    vec3 t = (tex_dy.t * pos_dx - tex_dx.t * pos_dy) / (tex_dx.s * tex_dy.t - tex_dy.s * tex_dx.t);

#ifdef NORMAL_LOC
    vec3 ng = normalize(frag_normal);
#else
    vec3 = cross(pos_dx, pos_dy);
#endif

    t = normalize(t - ng * dot(ng, t));
    vec3 b = normalize(cross(ng, t));
    mat3 tbn_n = mat3(t, b, ng);

#else

    mat3 tbn_n = tbn;

#endif

    vec3 n = texture(material.normal_texture, uv_0).rgb;
    n = normalize(tbn_n * ((2.0 * n - 1.0) * vec3(1.0, 1.0, 1.0)));
    return n; // TODO NORMAL MAPPING

#else

#ifdef NORMAL_LOC
    return frag_normal;
#else
    return normalize(cam_pos - frag_position);
#endif

#endif
}


///////////////////////////////////////////////////////////////////////////////
// MAIN
///////////////////////////////////////////////////////////////////////////////
void main()
{
    vec4 color = vec4(vec3(0.0), 1.0);
#ifdef USE_METALLIC_MATERIAL
    float metallic = clamp(material.metallic_factor, 0.0, 1.0);
    vec4 base_color = material.base_color_factor;
#ifdef HAS_BASE_COLOR_TEX
    base_color = base_color * srgb_to_linear(texture(material.base_color_texture, uv_0));
#endif
    // Lambert: the PBR diffuse term (1 - F0) c_diff / pi, F0 = 0.04 for a dielectric
    vec3 c_diff = mix(vec3(0.0), base_color.rgb * (1.0 - min_roughness), 1.0 - metallic)
                  * ((1.0 - min_roughness) / PI);
    vec3 n = normalize(get_normal());
    for (int i = 0; i < N_DIRECTIONAL; i++) {
        vec3 l = normalize(-1.0 * directional_lights[i].direction);
        float nl = clamp(dot(n, l), 0.0, 1.0);
        color.xyz += nl * directional_lights[i].intensity * directional_lights[i].color * c_diff;
    }
    for (int i = 0; i < N_POINT; i++) {
        vec3 d = point_lights[i].position - frag_position;
        float dist2 = dot(d, d);
        float nl = clamp(dot(n, d) * inversesqrt(dist2), 0.0, 1.0);
        color.xyz += nl * point_lights[i].intensity / dist2 * point_lights[i].color * c_diff;
    }
    for (int i = 0; i < N_SPOT; i++) {
        vec3 d = spot_lights[i].position - frag_position;
        float dist2 = dot(d, d);
        vec3 l = d * inversesqrt(dist2);
        float cd = clamp(dot(spot_lights[i].direction, -l), 0.0, 1.0);
        float a = clamp(cd * spot_lights[i].light_angle_scale
                        + spot_lights[i].light_angle_offset, 0.0, 1.0);
        float nl = clamp(dot(n, l), 0.0, 1.0);
        color.xyz += nl * a * a * spot_lights[i].intensity / dist2 * spot_lights[i].color
                     * c_diff;
    }
    color.xyz += base_color.xyz * ambient_light;
    vec3 emissive = material.emissive_factor;
#ifdef HAS_EMISSIVE_TEX
    emissive *= srgb_to_linear(texture(material.emissive_texture, uv_0)).rgb;
#endif
    color.xyz += emissive * material.emissive_factor;
#ifdef COLOR_0_LOC
    color *= color_multiplier;
#endif
    frag_color = clamp(vec4(pow(color.xyz, vec3(1.0/2.2)), color.a * base_color.a), 0.0, 1.0);
#endif
}
