#ifndef HOTPATH_H
#define HOTPATH_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define HP_ABI_VERSION 1u

#define HP_OK 0
#define HP_ERROR 1
#define HP_NOT_SUPPORTED 2

#define HP_DTYPE_F32 0u
#define HP_DTYPE_F64 1u
#define HP_DTYPE_I32 2u
#define HP_DTYPE_U32 3u
#define HP_DTYPE_U8 4u

#define HP_MEM_HOST 0u
#define HP_MEM_DEVICE 1u

#define HP_MAX_DIMS 4

#define HP_BACKEND_CPU 0u
#define HP_BACKEND_GPU 1u

#define HP_CAMERA_PINHOLE 0u
#define HP_CAMERA_ORTHO 1u

#define HP_SAMPLING_FIXED 0u
#define HP_SAMPLING_STRATIFIED 1u

#define HP_TRANS_PRODUCT 0u
#define HP_TRANS_LOG 1u

#define HP_INTERP_TRILINEAR 0u

#define HP_OOB_ZERO 0u
#define HP_OOB_CLAMP 1u

#define HP_ANALYTIC_CONSTANT 0u
#define HP_ANALYTIC_SLABS 1u
#define HP_ANALYTIC_GAUSSIAN 2u
#define HP_ANALYTIC_SHELL 3u
#define HP_ANALYTIC_LINEAR 4u

#define HP_STAGE_RAY 0u
#define HP_STAGE_SAMP 1u
#define HP_STAGE_INT 2u
#define HP_STAGE_IMG 3u
#define HP_STAGE_DIFF 4u

#define HP_CAP_CPU 1ull
#define HP_CAP_GPU 2ull
#define HP_CAP_F32 4ull
#define HP_CAP_F64 8ull
#define HP_CAP_FIELD_GRID 16ull
#define HP_CAP_FIELD_ANALYTIC 32ull
#define HP_CAP_FIELD_HASH_MLP 64ull
#define HP_CAP_DIFF 128ull

typedef int32_t hp_status;

typedef struct hp_ctx hp_ctx;
typedef struct hp_plan hp_plan;
typedef struct hp_field hp_field;

typedef struct hp_header {
    uint32_t abi_version;
    uint32_t reserved;
    uint64_t caps;
} hp_header;

typedef struct hp_tensor {
    void* data;
    uint32_t dtype;
    uint32_t memspace;
    uint32_t ndim;
    uint32_t reserved;
    int64_t shape[HP_MAX_DIMS];
    int64_t stride[HP_MAX_DIMS];
} hp_tensor;

typedef struct hp_camera {
    uint32_t kind;
    uint32_t width;
    uint32_t height;
    uint32_t reserved;
    double fx;
    double fy;
    double cx;
    double cy;
    double half_width;
    double half_height;
    double c2w[12];
} hp_camera;

typedef struct hp_plan_desc {
    const void* next;
    uint32_t backend;
    uint32_t precision;
    hp_camera camera;
    double aabb_min[3];
    double aabb_max[3];
    double near_t;
    double far_t;
    double dt;
    double early_stop;
    double background[3];
    uint32_t max_steps;
    uint32_t sampling;
    uint32_t seed;
    uint32_t trans_path;
} hp_plan_desc;

typedef struct hp_rays_t {
    const void* next;
    uint64_t count;
    hp_tensor o;
    hp_tensor d;
    hp_tensor t0;
    hp_tensor t1;
    hp_tensor pixel;
} hp_rays_t;

typedef struct hp_samp_t {
    const void* next;
    uint64_t capacity;
    uint64_t count;
    hp_tensor off;
    hp_tensor flags;
    hp_tensor ray_id;
    hp_tensor t;
    hp_tensor dt;
    hp_tensor sigma;
    hp_tensor color;
} hp_samp_t;

typedef struct hp_intl_t {
    const void* next;
    hp_tensor rgb;
    hp_tensor trans;
    hp_tensor logtrans;
    hp_tensor depth;
    hp_tensor opacity;
    hp_tensor nsamples;
    hp_tensor flags;
    hp_tensor alpha;
    hp_tensor log_t;
} hp_intl_t;

typedef struct hp_img_t {
    const void* next;
    hp_tensor rgb;
    hp_tensor trans;
    hp_tensor logtrans;
    hp_tensor depth;
    hp_tensor opacity;
    hp_tensor hit;
    hp_tensor nsamples;
} hp_img_t;

typedef struct hp_grads_t {
    const void* next;
    const hp_field* fs;
    const hp_field* fc;
    const hp_rays_t* rays;
    hp_tensor dsigma;
    hp_tensor dcolor;
    hp_tensor dcam;
} hp_grads_t;

hp_status hp_get_header(hp_header* out);

hp_status hp_ctx_create(uint32_t abi_version, hp_ctx** out);
hp_status hp_ctx_destroy(hp_ctx* ctx);
const char* hp_ctx_last_error(const hp_ctx* ctx);
const char* hp_last_error(void);

hp_status hp_camera_pinhole_look_at(const double position[3], const double target[3], const double up[3], double fov_y_deg, uint32_t width, uint32_t height, hp_camera* out);
hp_status hp_camera_ortho_look_at(const double position[3], const double target[3], const double up[3], double half_width, double half_height, uint32_t width, uint32_t height, hp_camera* out);

hp_status hp_plan_desc_default(hp_plan_desc* out);
hp_status hp_plan_create(hp_ctx* ctx, const hp_plan_desc* desc, hp_plan** out);
hp_status hp_plan_destroy(hp_plan* plan);
hp_status hp_plan_ray_count(const hp_plan* plan, uint64_t* count);
hp_status hp_workspace_size(const hp_plan* plan, uint32_t stage, uint64_t n_rays, uint64_t n_samples, size_t* bytes);

hp_status hp_field_create_grid_sigma(const hp_ctx* ctx, const hp_tensor* grid, uint32_t interp, uint32_t oob, hp_field** out);
hp_status hp_field_create_grid_color(const hp_ctx* ctx, const hp_tensor* grid, uint32_t interp, uint32_t oob, hp_field** out);
hp_status hp_field_create_hash_mlp(const hp_ctx* ctx, const hp_tensor* params, hp_field** out);
hp_status hp_field_create_analytic(const hp_ctx* ctx, uint32_t kind, const double* params, size_t n_params, hp_field** out);
hp_status hp_field_create_color_constant(const hp_ctx* ctx, const double rgb[3], hp_field** out);
hp_status hp_field_destroy(hp_field* field);

hp_status hp_ray(const hp_plan* plan, const hp_rays_t* override_or_null, hp_rays_t* rays, void* ws, size_t ws_bytes);
hp_status hp_samp(const hp_plan* plan, const hp_field* fs, const hp_field* fc, const hp_rays_t* rays, hp_samp_t* samp, void* ws, size_t ws_bytes);
hp_status hp_int(const hp_plan* plan, const hp_samp_t* samp, hp_intl_t* intl, void* ws, size_t ws_bytes);
hp_status hp_img(const hp_plan* plan, const hp_intl_t* intl, const hp_rays_t* rays, hp_img_t* img, void* ws, size_t ws_bytes);
hp_status hp_diff(const hp_plan* plan, const hp_tensor* dL_dI, const hp_samp_t* samp, const hp_intl_t* intl, hp_grads_t* grads, void* ws, size_t ws_bytes);

#ifdef __cplusplus
}
#endif

#endif
