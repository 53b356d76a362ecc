/* The C ABI's own test (issue 20), driven by capi/tests/c_abi.rs:
 *
 *   hp_test gen DIR    writes the inputs it will render: DIR/grid.npy (a
 *                      24^3 density), DIR/color.npy (24^3 x 3), DIR/w.npy
 *                      (dL/dI, 48x40x3), all float32
 *   hp_test check DIR  renders vol_gaussian (f32 and f64) and the grid scene
 *                      through hp_ray -> hp_samp -> hp_int -> hp_img, runs
 *                      hp_diff, compares every output bit for bit with what
 *                      `hpjudge render` wrote under DIR/ref_*, then runs the
 *                      misuse cases; exit 0 when everything holds.
 */
#include "hotpath.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static int failures = 0;

#define CHECK(cond, ...)                     \
    do {                                     \
        if (!(cond)) {                       \
            fprintf(stderr, "FAIL: ");       \
            fprintf(stderr, __VA_ARGS__);    \
            fprintf(stderr, "\n");           \
            failures++;                      \
        }                                    \
    } while (0)

/* ---- .npy reading and writing (C order, little-endian) ---- */

typedef struct npy {
    char descr[8];
    int ndim;
    long shape[4];
    size_t count;
    size_t itemsize;
    unsigned char* data;
} npy;

static int npy_read(const char* path, npy* out) {
    FILE* f = fopen(path, "rb");
    unsigned char magic[10];
    unsigned hlen;
    char* header;
    const char* p;
    size_t i;
    memset(out, 0, sizeof(*out));
    if (!f) return 0;
    if (fread(magic, 1, 10, f) != 10 || memcmp(magic, "\x93NUMPY", 6) != 0 || magic[6] != 1) {
        fclose(f);
        return 0;
    }
    hlen = magic[8] | (magic[9] << 8);
    header = (char*)calloc(hlen + 1, 1);
    if (fread(header, 1, hlen, f) != hlen) {
        free(header);
        fclose(f);
        return 0;
    }
    p = strstr(header, "'descr': '");
    if (p) {
        sscanf(p + 10, "%7[^']", out->descr);
    }
    out->itemsize = (size_t)atoi(out->descr + 2);
    p = strstr(header, "'shape': (");
    out->count = 1;
    if (p) {
        p += 10;
        while (*p && *p != ')' && out->ndim < 4) {
            char* end;
            long v = strtol(p, &end, 10);
            if (end == p) break;
            out->shape[out->ndim++] = v;
            out->count *= (size_t)v;
            p = end;
            while (*p == ',' || *p == ' ') p++;
        }
    }
    free(header);
    out->data = (unsigned char*)malloc(out->count * out->itemsize + 1);
    i = fread(out->data, out->itemsize, out->count, f);
    fclose(f);
    return i == out->count;
}

static void npy_write_f32(const char* path, const float* data, int ndim, const long* shape) {
    char header[128];
    char dims[64] = "";
    size_t count = 1;
    int i, n;
    FILE* f;
    for (i = 0; i < ndim; i++) {
        char d[24];
        sprintf(d, "%ld%s", shape[i], (ndim == 1 || i + 1 < ndim) ? ", " : "");
        strcat(dims, d);
        count *= (size_t)shape[i];
    }
    if (ndim > 1) dims[strlen(dims)] = '\0';
    n = sprintf(header, "{'descr': '<f4', 'fortran_order': False, 'shape': (%s), }", dims);
    while ((10 + n + 1) % 64 != 0) header[n++] = ' ';
    header[n++] = '\n';
    f = fopen(path, "wb");
    fwrite("\x93NUMPY\x01\x00", 1, 8, f);
    fputc(n & 0xff, f);
    fputc((n >> 8) & 0xff, f);
    fwrite(header, 1, (size_t)n, f);
    fwrite(data, sizeof(float), count, f);
    fclose(f);
}

/* ---- tensor views ---- */

static hp_tensor view(void* data, uint32_t dtype, int ndim, const int64_t* shape) {
    hp_tensor t;
    int i;
    int64_t s = 1;
    memset(&t, 0, sizeof(t));
    t.data = data;
    t.dtype = dtype;
    t.memspace = HP_MEM_HOST;
    t.ndim = (uint32_t)ndim;
    for (i = ndim - 1; i >= 0; i--) {
        t.shape[i] = shape[i];
        t.stride[i] = s;
        s *= shape[i];
    }
    return t;
}

static hp_tensor v1(void* d, uint32_t dt, int64_t a) {
    int64_t s[1];
    s[0] = a;
    return view(d, dt, 1, s);
}

static hp_tensor v2(void* d, uint32_t dt, int64_t a, int64_t b) {
    int64_t s[2];
    s[0] = a;
    s[1] = b;
    return view(d, dt, 2, s);
}

static hp_tensor v3(void* d, uint32_t dt, int64_t a, int64_t b, int64_t c) {
    int64_t s[3];
    s[0] = a;
    s[1] = b;
    s[2] = c;
    return view(d, dt, 3, s);
}

static hp_tensor v4(void* d, uint32_t dt, int64_t a, int64_t b, int64_t c, int64_t e) {
    int64_t s[4];
    s[0] = a;
    s[1] = b;
    s[2] = c;
    s[3] = e;
    return view(d, dt, 4, s);
}

/* ---- one render through the four stages (and optionally the backward) ---- */

typedef struct frame {
    uint32_t dtype;
    size_t fsz;
    uint64_t n;
    uint64_t m;
    void* ws;
    size_t ws_bytes;
    hp_rays_t rays;
    hp_samp_t samp;
    hp_intl_t intl;
    hp_img_t img;
    void* bufs[32];
    int nbufs;
} frame;

static void* alloc(frame* fr, size_t bytes) {
    void* p = calloc(bytes ? bytes : 1, 1);
    fr->bufs[fr->nbufs++] = p;
    return p;
}

static void frame_free(frame* fr) {
    int i;
    for (i = 0; i < fr->nbufs; i++) free(fr->bufs[i]);
    free(fr->ws);
}

static void use_ws(frame* fr, const hp_plan* plan, uint32_t stage, uint64_t n, uint64_t m) {
    size_t need = 0;
    CHECK(hp_workspace_size(plan, stage, n, m, &need) == HP_OK, "workspace size: %s", hp_last_error());
    if (need > fr->ws_bytes) {
        free(fr->ws);
        fr->ws = malloc(need);
        fr->ws_bytes = need;
    }
}

static int render(hp_ctx* ctx, const hp_plan* plan, const hp_field* fs, const hp_field* fc, uint32_t dtype, frame* fr) {
    uint64_t n, m;
    size_t fsz = dtype == HP_DTYPE_F64 ? 8 : 4;
    memset(fr, 0, sizeof(*fr));
    fr->dtype = dtype;
    fr->fsz = fsz;
    if (hp_plan_ray_count(plan, &n) != HP_OK) return 0;
    fr->n = n;
    fr->rays.count = n;
    fr->rays.o = v2(alloc(fr, n * 3 * fsz), dtype, (int64_t)n, 3);
    fr->rays.d = v2(alloc(fr, n * 3 * fsz), dtype, (int64_t)n, 3);
    fr->rays.t0 = v1(alloc(fr, n * fsz), dtype, (int64_t)n);
    fr->rays.t1 = v1(alloc(fr, n * fsz), dtype, (int64_t)n);
    fr->rays.pixel = v1(alloc(fr, n * 4), HP_DTYPE_U32, (int64_t)n);
    use_ws(fr, plan, HP_STAGE_RAY, n, 0);
    if (hp_ray(plan, NULL, &fr->rays, fr->ws, fr->ws_bytes) != HP_OK) {
        fprintf(stderr, "hp_ray: %s\n", hp_ctx_last_error(ctx));
        return 0;
    }
    /* Query the sample count (capacity 0, no buffers), then allocate. */
    use_ws(fr, plan, HP_STAGE_SAMP, n, n * 1024);
    if (hp_samp(plan, fs, fc, &fr->rays, &fr->samp, fr->ws, fr->ws_bytes) != HP_OK) {
        fprintf(stderr, "hp_samp (query): %s\n", hp_ctx_last_error(ctx));
        return 0;
    }
    m = fr->samp.count;
    fr->m = m;
    fr->samp.capacity = m;
    fr->samp.off = v1(alloc(fr, (n + 1) * 4), HP_DTYPE_U32, (int64_t)n + 1);
    fr->samp.flags = v1(alloc(fr, n), HP_DTYPE_U8, (int64_t)n);
    fr->samp.ray_id = v1(alloc(fr, m * 4), HP_DTYPE_U32, (int64_t)m);
    fr->samp.t = v1(alloc(fr, m * fsz), dtype, (int64_t)m);
    fr->samp.dt = v1(alloc(fr, m * fsz), dtype, (int64_t)m);
    fr->samp.sigma = v1(alloc(fr, m * fsz), dtype, (int64_t)m);
    fr->samp.color = v2(alloc(fr, m * 3 * fsz), dtype, (int64_t)m, 3);
    if (hp_samp(plan, fs, fc, &fr->rays, &fr->samp, fr->ws, fr->ws_bytes) != HP_OK) {
        fprintf(stderr, "hp_samp: %s\n", hp_ctx_last_error(ctx));
        return 0;
    }
    fr->intl.rgb = v2(alloc(fr, n * 3 * fsz), dtype, (int64_t)n, 3);
    fr->intl.trans = v1(alloc(fr, n * fsz), dtype, (int64_t)n);
    fr->intl.logtrans = v1(alloc(fr, n * fsz), dtype, (int64_t)n);
    fr->intl.depth = v1(alloc(fr, n * fsz), dtype, (int64_t)n);
    fr->intl.opacity = v1(alloc(fr, n * fsz), dtype, (int64_t)n);
    fr->intl.nsamples = v1(alloc(fr, n * 4), HP_DTYPE_I32, (int64_t)n);
    fr->intl.flags = v1(alloc(fr, n), HP_DTYPE_U8, (int64_t)n);
    fr->intl.alpha = v1(alloc(fr, m * fsz), dtype, (int64_t)m);
    fr->intl.log_t = v1(alloc(fr, m * fsz), dtype, (int64_t)m);
    use_ws(fr, plan, HP_STAGE_INT, n, m);
    if (hp_int(plan, &fr->samp, &fr->intl, fr->ws, fr->ws_bytes) != HP_OK) {
        fprintf(stderr, "hp_int: %s\n", hp_ctx_last_error(ctx));
        return 0;
    }
    return 1;
}

static int compose(hp_ctx* ctx, const hp_plan* plan, frame* fr, uint32_t width, uint32_t height) {
    size_t px = (size_t)width * height, fsz = fr->fsz;
    uint32_t dt = fr->dtype;
    fr->img.rgb = v3(alloc(fr, px * 3 * fsz), dt, height, width, 3);
    fr->img.trans = v2(alloc(fr, px * fsz), dt, height, width);
    fr->img.logtrans = v2(alloc(fr, px * fsz), dt, height, width);
    fr->img.depth = v2(alloc(fr, px * fsz), dt, height, width);
    fr->img.opacity = v2(alloc(fr, px * fsz), dt, height, width);
    fr->img.hit = v2(alloc(fr, px), HP_DTYPE_U8, height, width);
    fr->img.nsamples = v2(alloc(fr, px * 4), HP_DTYPE_I32, height, width);
    if (hp_img(plan, &fr->intl, &fr->rays, &fr->img, NULL, 0) != HP_OK) {
        fprintf(stderr, "hp_img: %s\n", hp_ctx_last_error(ctx));
        return 0;
    }
    return 1;
}

/* Compares `bytes` of `data` with the payload of DIR/NAME.npy. */
static void same(const char* dir, const char* name, const void* data, size_t bytes, const char* want_descr) {
    char path[1024];
    npy r;
    sprintf(path, "%s/%s.npy", dir, name);
    if (!npy_read(path, &r)) {
        CHECK(0, "cannot read %s", path);
        return;
    }
    CHECK(strcmp(r.descr, want_descr) == 0, "%s: dtype %s, expected %s", path, r.descr, want_descr);
    CHECK(r.count * r.itemsize == bytes, "%s: %lu bytes, ours %lu", path, (unsigned long)(r.count * r.itemsize), (unsigned long)bytes);
    if (r.count * r.itemsize == bytes) {
        CHECK(memcmp(r.data, data, bytes) == 0, "%s: differs from the C ABI's output", path);
    }
    free(r.data);
}

static void same_image(const char* dir, const frame* fr, uint32_t width, uint32_t height) {
    size_t px = (size_t)width * height, fsz = fr->fsz;
    const char* fd = fsz == 8 ? "<f8" : "<f4";
    same(dir, "rgb", fr->img.rgb.data, px * 3 * fsz, fd);
    same(dir, "trans", fr->img.trans.data, px * fsz, fd);
    same(dir, "logtrans", fr->img.logtrans.data, px * fsz, fd);
    same(dir, "depth", fr->img.depth.data, px * fsz, fd);
    same(dir, "opacity", fr->img.opacity.data, px * fsz, fd);
    same(dir, "hit", fr->img.hit.data, px, "|u1");
    same(dir, "nsamples", fr->img.nsamples.data, px * 4, "<i4");
}

static hp_plan* make_plan(hp_ctx* ctx, uint32_t precision, uint32_t width, uint32_t height) {
    hp_plan_desc d;
    hp_plan* plan = NULL;
    double pos[3] = {0, 0, 3}, target[3] = {0, 0, 0}, up[3] = {0, 1, 0};
    CHECK(hp_plan_desc_default(&d) == HP_OK, "desc default");
    CHECK(hp_camera_pinhole_look_at(pos, target, up, 40.0, width, height, &d.camera) == HP_OK, "look_at: %s", hp_last_error());
    d.precision = precision;
    CHECK(hp_plan_create(ctx, &d, &plan) == HP_OK, "plan: %s", hp_ctx_last_error(ctx));
    return plan;
}

/* SCENES.md vol_gaussian through the four stages. */
static void check_gaussian(hp_ctx* ctx, const char* dir, uint32_t precision, const char* sub) {
    double gp[5] = {20, 0, 0, 0, 0.3}, c[3] = {1, 0.5, 0.25};
    hp_field *fs = NULL, *fc = NULL;
    hp_plan* plan = make_plan(ctx, precision, 64, 64);
    frame fr;
    char ref[1024];
    CHECK(hp_field_create_analytic(ctx, HP_ANALYTIC_GAUSSIAN, gp, 5, &fs) == HP_OK, "gaussian: %s", hp_ctx_last_error(ctx));
    CHECK(hp_field_create_color_constant(ctx, c, &fc) == HP_OK, "colour: %s", hp_ctx_last_error(ctx));
    if (plan && fs && fc && render(ctx, plan, fs, fc, precision, &fr) && compose(ctx, plan, &fr, 64, 64)) {
        sprintf(ref, "%s/%s", dir, sub);
        same_image(ref, &fr, 64, 64);
        printf("vol_gaussian %s: %lu rays, %lu samples, compared with %s\n", precision == HP_DTYPE_F64 ? "f64" : "f32",
               (unsigned long)fr.n, (unsigned long)fr.m, ref);
        frame_free(&fr);
    } else {
        CHECK(0, "vol_gaussian render failed");
    }
    hp_field_destroy(fs);
    hp_field_destroy(fc);
    hp_plan_destroy(plan);
}

#define GN 24
#define GW 48
#define GH 40

static void gen(const char* dir) {
    static float grid[GN * GN * GN], color[GN * GN * GN * 3], w[GH * GW * 3];
    long gs[3] = {GN, GN, GN}, cs[4] = {GN, GN, GN, 3}, ws[3] = {GH, GW, 3};
    char path[1024];
    int i, j, k, c;
    for (k = 0; k < GN; k++)
        for (j = 0; j < GN; j++)
            for (i = 0; i < GN; i++) {
                double x = -1 + 2.0 * i / (GN - 1), y = -1 + 2.0 * j / (GN - 1), z = -1 + 2.0 * k / (GN - 1);
                double r2 = x * x + y * y + z * z;
                int at = (k * GN + j) * GN + i;
                grid[at] = (float)(8.0 * exp(-r2 / 0.3) + 2.0 * (x > 0.2 && y < 0.1));
                for (c = 0; c < 3; c++) color[at * 3 + c] = (float)(0.5 + 0.45 * sin(3.0 * x + 2.0 * c + y * (c + 1) - z));
            }
    for (i = 0; i < GH * GW * 3; i++) w[i] = (float)sin(0.37 * i) * 0.5f;
    sprintf(path, "%s/grid.npy", dir);
    npy_write_f32(path, grid, 3, gs);
    sprintf(path, "%s/color.npy", dir);
    npy_write_f32(path, color, 4, cs);
    sprintf(path, "%s/w.npy", dir);
    npy_write_f32(path, w, 3, ws);
}

/* The grid scene of c_abi.rs (pinhole at (0, 0, 3), fov 40, GW x GH) with
 * its backward for dL/dI = w.npy. */
static void check_grid(hp_ctx* ctx, const char* dir) {
    npy g, c, w;
    hp_field *fs = NULL, *fc = NULL;
    hp_plan* plan = make_plan(ctx, HP_DTYPE_F32, GW, GH);
    hp_tensor gt, ct, wt;
    frame fr;
    char path[1024], ref[1024];
    sprintf(path, "%s/grid.npy", dir);
    CHECK(npy_read(path, &g), "read %s", path);
    sprintf(path, "%s/color.npy", dir);
    CHECK(npy_read(path, &c), "read %s", path);
    sprintf(path, "%s/w.npy", dir);
    CHECK(npy_read(path, &w), "read %s", path);
    gt = v3(g.data, HP_DTYPE_F32, GN, GN, GN);
    ct = v4(c.data, HP_DTYPE_F32, GN, GN, GN, 3);
    wt = v3(w.data, HP_DTYPE_F32, GH, GW, 3);
    CHECK(hp_field_create_grid_sigma(ctx, &gt, HP_INTERP_TRILINEAR, HP_OOB_ZERO, &fs) == HP_OK, "grid sigma: %s", hp_ctx_last_error(ctx));
    CHECK(hp_field_create_grid_color(ctx, &ct, HP_INTERP_TRILINEAR, HP_OOB_ZERO, &fc) == HP_OK, "grid colour: %s", hp_ctx_last_error(ctx));
    if (plan && fs && fc && render(ctx, plan, fs, fc, HP_DTYPE_F32, &fr) && compose(ctx, plan, &fr, GW, GH)) {
        hp_grads_t gr;
        float* dsigma = (float*)calloc(GN * GN * GN, 4);
        float* dcolor = (float*)calloc(GN * GN * GN * 3, 4);
        float dcam[6];
        sprintf(ref, "%s/ref_grid", dir);
        same_image(ref, &fr, GW, GH);
        memset(&gr, 0, sizeof(gr));
        gr.fs = fs;
        gr.fc = fc;
        gr.rays = &fr.rays;
        gr.dsigma = v3(dsigma, HP_DTYPE_F32, GN, GN, GN);
        gr.dcolor = v4(dcolor, HP_DTYPE_F32, GN, GN, GN, 3);
        gr.dcam = v1(dcam, HP_DTYPE_F32, 6);
        use_ws(&fr, plan, HP_STAGE_DIFF, fr.n, fr.m);
        if (hp_diff(plan, &wt, &fr.samp, &fr.intl, &gr, fr.ws, fr.ws_bytes) == HP_OK) {
            same(ref, "dsigma", dsigma, GN * GN * GN * 4, "<f4");
            same(ref, "dcolor", dcolor, GN * GN * GN * 3 * 4, "<f4");
            same(ref, "dcam", dcam, 6 * 4, "<f4");
            printf("grid %dx%d: %lu samples; image, dsigma, dcolor, dcam compared with %s\n", GW, GH, (unsigned long)fr.m, ref);
        } else {
            CHECK(0, "hp_diff: %s", hp_ctx_last_error(ctx));
        }
        free(dsigma);
        free(dcolor);
        frame_free(&fr);
    } else {
        CHECK(0, "grid render failed");
    }
    free(g.data);
    free(c.data);
    free(w.data);
    hp_field_destroy(fs);
    hp_field_destroy(fc);
    hp_plan_destroy(plan);
}

/* Wrong calls: each gets its status and a message naming the argument. */
static void expect(hp_status got, hp_status want, const char* what, const char* needle) {
    const char* msg = hp_last_error();
    CHECK(got == want, "%s: status %d, expected %d (%s)", what, (int)got, (int)want, msg);
    CHECK(strstr(msg, needle) != NULL, "%s: message \"%s\" does not name \"%s\"", what, msg, needle);
    printf("misuse %-34s -> %d: %s\n", what, (int)got, msg);
}

static void check_misuse(hp_ctx* ctx) {
    hp_plan* plan = make_plan(ctx, HP_DTYPE_F32, 8, 8);
    hp_plan* p64 = make_plan(ctx, HP_DTYPE_F32, 8, 8);
    hp_plan_desc d;
    hp_plan* bad = NULL;
    hp_ctx* other = NULL;
    hp_field* f = NULL;
    hp_rays_t rays;
    double gp[5] = {20, 0, 0, 0, 0.3}, c[3] = {1, 0.5, 0.25};
    hp_field *fs = NULL, *fc = NULL;
    static float obuf[64 * 3], dbuf[64 * 3], t0buf[64], t1buf[64], f32buf[64 * 3];
    static double f64buf[64 * 3];
    static char scratch[1 << 20];
    static uint32_t pix[64];
    char ws[16];
    hp_tensor t;
    (void)p64;
    hp_field_create_analytic(ctx, HP_ANALYTIC_GAUSSIAN, gp, 5, &fs);
    hp_field_create_color_constant(ctx, c, &fc);

    expect(hp_ctx_create(HP_ABI_VERSION + 1, &other), HP_NOT_SUPPORTED, "ctx for another ABI", "ABI");
    expect(hp_plan_create(ctx, NULL, &bad), HP_ERROR, "plan with NULL desc", "desc is NULL");
    hp_plan_desc_default(&d);
    expect(hp_plan_create(ctx, &d, &bad), HP_ERROR, "plan with no camera", "desc.camera");
    hp_plan_desc_default(&d);
    {
        double pos[3] = {0, 0, 3}, target[3] = {0, 0, 0}, up[3] = {0, 1, 0};
        hp_camera_pinhole_look_at(pos, target, up, 40.0, 8, 8, &d.camera);
    }
    d.backend = HP_BACKEND_GPU;
    expect(hp_plan_create(ctx, &d, &bad), HP_NOT_SUPPORTED, "plan on the GPU backend", "HP_BACKEND_GPU");
    d.backend = HP_BACKEND_CPU;
    d.dt = -1;
    expect(hp_plan_create(ctx, &d, &bad), HP_ERROR, "plan with dt < 0", "dt");
    d.dt = 0.01;
    d.next = &d;
    expect(hp_plan_create(ctx, &d, &bad), HP_NOT_SUPPORTED, "plan with an unknown next chain", "next");
    expect(hp_ray(NULL, NULL, &rays, NULL, 0), HP_ERROR, "hp_ray with NULL plan", "plan is NULL");

    memset(&rays, 0, sizeof(rays));
    rays.count = 64;
    rays.o = v2(f64buf, HP_DTYPE_F64, 64, 3);
    rays.d = v2(dbuf, HP_DTYPE_F32, 64, 3);
    rays.t0 = v1(t0buf, HP_DTYPE_F32, 64);
    rays.t1 = v1(t1buf, HP_DTYPE_F32, 64);
    rays.pixel = v1(pix, HP_DTYPE_U32, 64);
    expect(hp_ray(plan, NULL, &rays, scratch, 1 << 20), HP_ERROR, "hp_ray with an f64 tensor on an f32 plan", "rays.o: dtype F64");
    rays.o = v2(obuf, HP_DTYPE_F32, 64, 3);
    rays.d = v2(NULL, HP_DTYPE_F32, 64, 3);
    expect(hp_ray(plan, NULL, &rays, scratch, 1 << 20), HP_ERROR, "hp_ray with a NULL tensor", "rays.d: data is NULL");
    rays.d = v2(dbuf, HP_DTYPE_F32, 63, 3);
    expect(hp_ray(plan, NULL, &rays, scratch, 1 << 20), HP_ERROR, "hp_ray with a wrong shape", "rays.d: extent 63");
    rays.d = v2(dbuf, HP_DTYPE_F32, 64, 3);
    expect(hp_ray(plan, NULL, &rays, ws, sizeof(ws)), HP_ERROR, "hp_ray with a too-small workspace", "needs");
    expect(hp_ray(plan, NULL, &rays, NULL, 4096), HP_ERROR, "hp_ray with NULL ws and ws_bytes", "ws is NULL");
    t = v1(f32buf, HP_DTYPE_F32, 8);
    t.memspace = HP_MEM_DEVICE;
    expect(hp_field_create_grid_sigma(ctx, &t, HP_INTERP_TRILINEAR, HP_OOB_ZERO, &f), HP_NOT_SUPPORTED, "grid in device memory", "memspace");
    t = v3(f32buf, HP_DTYPE_F32, 4, 4, 4);
    f32buf[5] = (float)NAN;
    expect(hp_field_create_grid_sigma(ctx, &t, HP_INTERP_TRILINEAR, HP_OOB_ZERO, &f), HP_ERROR, "grid with a NaN", "grid");
    f32buf[5] = 0;
    expect(hp_field_create_grid_sigma(ctx, &t, 7, HP_OOB_ZERO, &f), HP_NOT_SUPPORTED, "grid with unknown interp", "interp");
    expect(hp_field_create_hash_mlp(ctx, &t, &f), HP_NOT_SUPPORTED, "hash-MLP field", "hash");
    expect(hp_field_create_analytic(ctx, HP_ANALYTIC_GAUSSIAN, gp, 2, &f), HP_ERROR, "gaussian with 2 params", "5 values");
    expect(hp_samp(plan, fc, fs, &rays, NULL, NULL, 0), HP_ERROR, "hp_samp with NULL samp", "samp is NULL");
    {
        hp_samp_t s;
        size_t wsb = 0;
        char* big;
        memset(&s, 0, sizeof(s));
        hp_workspace_size(plan, HP_STAGE_RAY, 64, 0, &wsb);
        big = (char*)malloc(wsb + (1 << 20));
        CHECK(hp_ray(plan, NULL, &rays, big, wsb) == HP_OK, "hp_ray with the queried workspace: %s", hp_last_error());
        expect(hp_samp(plan, fc, fs, &rays, &s, big, wsb + (1 << 20)), HP_ERROR, "hp_samp with fields swapped", "fs: a colour field");
        s.capacity = 3;
        expect(hp_samp(plan, fs, fc, &rays, &s, big, wsb + (1 << 20)), HP_ERROR, "hp_samp with too small a capacity", "samp.capacity is 3");
        free(big);
    }
    expect(hp_img(plan, NULL, &rays, NULL, NULL, 0), HP_ERROR, "hp_img with NULL intl", "intl is NULL");
    hp_field_destroy(fs);
    hp_field_destroy(fc);
    hp_plan_destroy(plan);
    hp_plan_destroy(p64);
}

int main(int argc, char** argv) {
    hp_ctx* ctx = NULL;
    hp_header hdr;
    if (argc != 3) {
        fprintf(stderr, "usage: hp_test gen|check DIR\n");
        return 2;
    }
    if (strcmp(argv[1], "gen") == 0) {
        gen(argv[2]);
        return 0;
    }
    CHECK(hp_get_header(&hdr) == HP_OK, "header");
    CHECK(hdr.abi_version == HP_ABI_VERSION, "ABI %u", hdr.abi_version);
    CHECK((hdr.caps & HP_CAP_CPU) && (hdr.caps & HP_CAP_DIFF), "caps %llx", (unsigned long long)hdr.caps);
    CHECK(hp_ctx_create(HP_ABI_VERSION, &ctx) == HP_OK, "ctx: %s", hp_last_error());
    check_gaussian(ctx, argv[2], HP_DTYPE_F32, "ref_gauss_f32");
    check_gaussian(ctx, argv[2], HP_DTYPE_F64, "ref_gauss_f64");
    check_grid(ctx, argv[2]);
    check_misuse(ctx);
    hp_ctx_destroy(ctx);
    if (failures) {
        fprintf(stderr, "%d checks failed\n", failures);
        return 1;
    }
    printf("all C ABI checks passed\n");
    return 0;
}
