/* NavFormer's causal transformer on a few new tokens against a key/value cache, in one call.
 *
 * The same maths as navformer_rl.modules.decoding.transformer_step.TransformerStep (pre-LN GPT-2 blocks:
 * x += proj(attn(ln_attn(x))); x += out(gelu(fc(ln_mlp(x)))); then ln_final), written for the few rows
 * of an inference step: at 4 rows every BLAS call of the torch path re-packs its weight matrix, and the
 * attention kernel is built for long query blocks. Here each Linear is a 4 x 64 register-blocked loop
 * that streams its [in, out] weight once per 4 rows, and attention reads a key cache blocked by 16 slots
 * ([B, H, ceil(S / 16), d_head, 16]: 16 slots' scores per vector operation) and a value cache
 * [B, H, S, d_head], each head's once for all new tokens.
 *
 * float32 throughout; results equal the torch path up to float rounding (different summation order).
 * exp, erf and tanh are computed with the polynomial approximations ATen's vectorised CPU kernels use.
 * Built by navformer_rl.modules.decoding.native.build with the system C compiler (-O3 -march=native);
 * GCC vector extensions, no intrinsics, so it compiles (and vectorises) on any target GCC or clang knows.
 * The caller (step.py) checks every shape and index: nothing here is bounds-checked.
 */
#include <math.h>
#include <stdint.h>
#include <string.h>

typedef float v16 __attribute__((vector_size(64)));
typedef int32_t v16i __attribute__((vector_size(64)));

#define INLINE static inline __attribute__((always_inline))

static inline v16 load16(const float *p) { v16 v; memcpy(&v, p, sizeof v); return v; }
static inline void store16(float *p, v16 v) { memcpy(p, &v, sizeof v); }
static inline v16 splat(float x) { return (v16){0} + x; }
/* lanes of a where m is set (all ones), of b elsewhere (C has no ternary on vectors) */
static inline v16 select16(v16i m, v16 a, v16 b) {
    v16i ai, bi;
    memcpy(&ai, &a, sizeof ai);
    memcpy(&bi, &b, sizeof bi);
    ai = (ai & m) | (bi & ~m);
    memcpy(&a, &ai, sizeof a);
    return a;
}

typedef struct {
    const float *ln_attn_weight, *ln_attn_bias;
    const float *qkv_weight, *qkv_bias;   /* [d, 3 H dh] (in, out), [3 H dh] */
    const float *proj_weight, *proj_bias; /* [H dh, d], [d] */
    const float *ln_mlp_weight, *ln_mlp_bias;
    const float *fc_weight, *fc_bias;     /* [d, hidden], [hidden] */
    const float *out_weight, *out_bias;   /* [hidden, d], [d] */
    float *keys_blocked;                  /* [B, H, ceil(S / 16), dh, 16] */
    float *values;                        /* [B, H, S, dh] */
    double ln_attn_eps, ln_mlp_eps;
} Block;

typedef struct {
    int64_t batch, length, d, heads, d_head, hidden, slots, used, n_blocks, gelu_tanh;
    const float *x;               /* [B * L, d] */
    float *out;                   /* [B * L, d] */
    const int64_t *write_slots;   /* cache slot of token l of sequence b: write_slots[b * stride + l], */
    int64_t write_slots_batch_stride; /* or write_start + l for every b when write_slots is NULL */
    int64_t write_start;
    const float *mask;            /* additive [., L, >= used]: mask[b * batch_stride + i * row_stride + s] */
    int64_t mask_batch_stride, mask_row_stride;
    const float *ln_final_weight, *ln_final_bias;
    double ln_final_eps;
    float *scratch;               /* navformer_step_scratch_floats(...) floats */
    const Block *blocks;
} Step;

/* ---- elementwise functions (ATen's vectorised float formulas) ---- */

static inline v16 exp16(v16 x) {
    /* Cephes expf: x = n ln2 + r, |r| <= ln2 / 2, degree-5 polynomial for e^r; 0 below -87.3 */
    const v16 hi = splat(88.3762626647949f), lo = splat(-87.3365478515625f);
    v16i below = x < lo;
    x = select16(x > hi, hi, x);
    x = select16(below, lo, x);
    v16 n = x * 1.44269504088896341f + 12582912.0f;
    n = n - 12582912.0f; /* round to nearest */
    v16 r = x - n * 0.693359375f;
    r = r - n * -2.12194440e-4f;
    v16 p = splat(1.9875691500E-4f);
    p = p * r + 1.3981999507E-3f;
    p = p * r + 8.3334519073E-3f;
    p = p * r + 4.1665795894E-2f;
    p = p * r + 1.6666665459E-1f;
    p = p * r + 5.0000001201E-1f;
    p = p * (r * r) + r + 1.0f;
    v16i bits = (__builtin_convertvector(n, v16i) + 127) << 23;
    v16 scale;
    memcpy(&scale, &bits, sizeof scale);
    return select16(below, splat(0.0f), p * scale);
}

static inline v16 erf16(v16 x) {
    /* Abramowitz & Stegun 7.1.26 (|error| < 1.5e-7), as ATen's Vectorized<float>::erf */
    v16 a = select16(x < 0, -x, x);
    v16 t = 1.0f / (a * 0.3275911f + 1.0f);
    v16 r = splat(1.061405429f);
    r = r * t - 1.453152027f;
    r = r * t + 1.421413741f;
    r = r * t - 0.284496736f;
    r = r * t + 0.254829592f;
    r = r * t;
    v16 y = 1.0f - r * exp16(-x * x);
    return select16(x < 0, -y, y);
}

static inline v16 tanh16(v16 x) {
    /* tanh(x) = 1 - 2 / (e^(2x) + 1); exact sign and saturation at both ends */
    v16 e = exp16(2.0f * x);
    return 1.0f - 2.0f / (e + 1.0f);
}

static void gelu(float *x, int64_t n, int64_t tanh_form) {
    for (int64_t i = 0; i < n; i += 16) {
        v16 v = load16(x + i);
        v16 y;
        if (tanh_form) {
            v16 inner = 0.7978845608028654f * (v + 0.044715f * v * v * v);
            y = 0.5f * v * (1.0f + tanh16(inner));
        } else {
            y = 0.5f * v * (1.0f + erf16(v * 0.7071067811865476f));
        }
        store16(x + i, y);
    }
}

/* ---- LayerNorm over rows of d (two-pass mean / variance, biased variance as torch) ---- */

static void layer_norm(const float *x, float *y, int64_t rows, int64_t d, const float *w, const float *b, double eps) {
    for (int64_t r = 0; r < rows; r++) {
        const float *xr = x + r * d;
        float *yr = y + r * d;
        v16 s = {0};
        for (int64_t j = 0; j < d; j += 16) s += load16(xr + j);
        float mean = 0;
        for (int k = 0; k < 16; k++) mean += s[k];
        mean /= (float)d;
        v16 q = {0};
        for (int64_t j = 0; j < d; j += 16) {
            v16 c = load16(xr + j) - mean;
            q += c * c;
        }
        float var = 0;
        for (int k = 0; k < 16; k++) var += q[k];
        var /= (float)d;
        float rstd = 1.0f / sqrtf(var + (float)eps);
        for (int64_t j = 0; j < d; j += 16)
            store16(yr + j, (load16(xr + j) - mean) * rstd * load16(w + j) + load16(b + j));
    }
}

/* ---- C[M, N] = bias + A[M, K] @ W[K, N] (+ residual, which may alias C) ---- */

/* `rows` and `vectors` are compile-time constants at every call (see the switches below), so the loops
   over them unroll and the accumulators stay in registers */
INLINE void gemm_tile_body(int rows, int vectors, int64_t K, int64_t N, const float *A, const float *W,
                           const float *bias, const float *res, float *C) {
    /* C[rows, 16 * vectors] = bias + A[rows, K] @ W[K, 16 * vectors] (+ res); rows <= 4, vectors <= 4 */
    v16 c[4][4], w[4];
    for (int j = 0; j < vectors; j++) {
        v16 bj = load16(bias + 16 * j);
        for (int m = 0; m < rows; m++) c[m][j] = bj;
    }
    for (int64_t k = 0; k < K; k++) {
        const float *wk = W + k * N;
        for (int j = 0; j < vectors; j++) w[j] = load16(wk + 16 * j);
        for (int m = 0; m < rows; m++) {
            float a = A[m * K + k];
            for (int j = 0; j < vectors; j++) c[m][j] += a * w[j];
        }
    }
    for (int m = 0; m < rows; m++)
        for (int j = 0; j < vectors; j++) {
            v16 v = c[m][j];
            if (res) v += load16(res + m * N + 16 * j);
            store16(C + m * N + 16 * j, v);
        }
}

#define GEMM_TILE(rows, vectors) gemm_tile_body(rows, vectors, K, N, A, W, bias, res, C)

static void gemm_tile(int64_t rows, int64_t vectors, int64_t K, int64_t N, const float *A, const float *W,
                      const float *bias, const float *res, float *C) {
    if (vectors == 4) {
        switch (rows) {
        case 4: GEMM_TILE(4, 4); break;
        case 3: GEMM_TILE(3, 4); break;
        case 2: GEMM_TILE(2, 4); break;
        default: GEMM_TILE(1, 4); break;
        }
    } else {
        switch (rows) {
        case 4: GEMM_TILE(4, 1); break;
        case 3: GEMM_TILE(3, 1); break;
        case 2: GEMM_TILE(2, 1); break;
        default: GEMM_TILE(1, 1); break;
        }
    }
}

static void gemm(int64_t M, int64_t N, int64_t K, const float *A, const float *W, const float *bias,
                 const float *res, float *C) {
    /* column tiles outer: a tile of W (K x 64 floats) is streamed once, then re-read from L1 / L2 for the
       other row tiles */
    int64_t n0 = 0;
    for (; n0 + 64 <= N; n0 += 64)
        for (int64_t m0 = 0; m0 < M; m0 += 4) {
            int64_t rows = M - m0 < 4 ? M - m0 : 4;
            gemm_tile(rows, 4, K, N, A + m0 * K, W + n0, bias + n0, res ? res + m0 * N + n0 : 0, C + m0 * N + n0);
        }
    for (; n0 < N; n0 += 16)
        for (int64_t m0 = 0; m0 < M; m0 += 4) {
            int64_t rows = M - m0 < 4 ? M - m0 : 4;
            gemm_tile(rows, 1, K, N, A + m0 * K, W + n0, bias + n0, res ? res + m0 * N + n0 : 0, C + m0 * N + n0);
        }
}

/* ---- attention of the L new tokens of every sequence over the first `used` cache slots ---- */

#define QUERY_BLOCK 4

static void write_cache(const Step *s, const Block *blk, const float *qkv) {
    /* keys go to keys_blocked [B, H, S / 16, dh, 16] (slot s at block s / 16, lane s % 16) */
    int64_t H = s->heads, dh = s->d_head, blocks = (s->slots + 15) / 16, hd = H * dh;
    for (int64_t b = 0; b < s->batch; b++)
        for (int64_t l = 0; l < s->length; l++) {
            int64_t slot = s->write_slots ? s->write_slots[b * s->write_slots_batch_stride + l] : s->write_start + l;
            const float *row = qkv + (b * s->length + l) * 3 * hd;
            for (int64_t h = 0; h < H; h++) {
                const float *k = row + hd + h * dh, *v = row + 2 * hd + h * dh;
                float *kb = blk->keys_blocked + ((b * H + h) * blocks + slot / 16) * dh * 16 + slot % 16;
                for (int64_t e = 0; e < dh; e++) kb[e * 16] = k[e];
                memcpy(blk->values + ((b * H + h) * s->slots + slot) * dh, v, dh * sizeof(float));
            }
        }
}

static float softmax_unnormalised(float *sc, int64_t padded) {
    /* sc <- exp(sc - max); returns the sum */
    v16 mx = splat(-INFINITY);
    for (int64_t j = 0; j < padded; j += 16) {
        v16 v = load16(sc + j);
        mx = select16(v > mx, v, mx);
    }
    float m = -INFINITY;
    for (int k = 0; k < 16; k++) m = mx[k] > m ? mx[k] : m;
    v16 total = {0};
    for (int64_t j = 0; j < padded; j += 16) {
        v16 p = exp16(load16(sc + j) - m);
        store16(sc + j, p);
        total += p;
    }
    float sum = 0;
    for (int k = 0; k < 16; k++) sum += total[k];
    return sum;
}

INLINE void scores_body(int nq, int64_t dh, int64_t used, const float *kb, const float *const *q,
                        const float *const *mask, float *const *sc) {
    /* sc[i][0 .. padded) = q_i . k_s / sqrt(dh) + mask_i[s] for s < used, -inf beyond; kb: one head's
       keys [S / 16, dh, 16] */
    float scale = 1.0f / sqrtf((float)dh);
    for (int64_t s0 = 0; s0 < used; s0 += 16) {
        v16 acc[QUERY_BLOCK];
        for (int i = 0; i < nq; i++) acc[i] = splat(0.0f);
        const float *kp = kb + (s0 / 16) * dh * 16;
        for (int64_t e = 0; e < dh; e++) {
            v16 k = load16(kp + e * 16);
            for (int i = 0; i < nq; i++) acc[i] += q[i][e] * k;
        }
        if (s0 + 16 <= used) {
            for (int i = 0; i < nq; i++) store16(sc[i] + s0, acc[i] * scale + load16(mask[i] + s0));
        } else {
            for (int i = 0; i < nq; i++)
                for (int64_t lane = 0; lane < 16; lane++)
                    sc[i][s0 + lane] = s0 + lane < used ? acc[i][lane] * scale + mask[i][s0 + lane] : -INFINITY;
        }
    }
}

INLINE void values_body(int nq, int vectors, int64_t dh, int64_t used, const float *vals,
                        float *const *sc, const float *inv, float *const *out) {
    /* out_i[0 .. 16 vectors) = inv_i * sum_{s < used} sc_i[s] v_s[0 .. 16 vectors): one pass over the
       values (vals: one head's [S, dh], offset to the first column) */
    v16 acc[QUERY_BLOCK][4], v[4];
    for (int i = 0; i < nq; i++)
        for (int c = 0; c < vectors; c++) acc[i][c] = splat(0.0f);
    for (int64_t j = 0; j < used; j++) {
        for (int c = 0; c < vectors; c++) v[c] = load16(vals + j * dh + 16 * c);
        for (int i = 0; i < nq; i++) {
            float p = sc[i][j];
            for (int c = 0; c < vectors; c++) acc[i][c] += p * v[c];
        }
    }
    for (int i = 0; i < nq; i++)
        for (int c = 0; c < vectors; c++) store16(out[i] + 16 * c, acc[i][c] * inv[i]);
}

static void attention_scores(int64_t nq, int64_t dh, int64_t used, const float *kb, const float *const *q,
                             const float *const *mask, float *const *sc) {
    switch (nq) {
    case 4: scores_body(4, dh, used, kb, q, mask, sc); break;
    case 3: scores_body(3, dh, used, kb, q, mask, sc); break;
    case 2: scores_body(2, dh, used, kb, q, mask, sc); break;
    default: scores_body(1, dh, used, kb, q, mask, sc); break;
    }
}

static void attention_values(int64_t nq, int64_t dh, int64_t used, const float *vals, float *const *sc,
                             const float *inv, float *const *out) {
    /* 64 columns of d_head per pass over the values, then 16 */
    int64_t e0 = 0;
    float *o[QUERY_BLOCK];
    for (; e0 < dh; e0 += e0 + 64 <= dh ? 64 : 16) {
        for (int64_t i = 0; i < nq; i++) o[i] = out[i] + e0;
        if (e0 + 64 <= dh) {
            switch (nq) {
            case 4: values_body(4, 4, dh, used, vals + e0, sc, inv, o); break;
            case 3: values_body(3, 4, dh, used, vals + e0, sc, inv, o); break;
            case 2: values_body(2, 4, dh, used, vals + e0, sc, inv, o); break;
            default: values_body(1, 4, dh, used, vals + e0, sc, inv, o); break;
            }
        } else {
            switch (nq) {
            case 4: values_body(4, 1, dh, used, vals + e0, sc, inv, o); break;
            case 3: values_body(3, 1, dh, used, vals + e0, sc, inv, o); break;
            case 2: values_body(2, 1, dh, used, vals + e0, sc, inv, o); break;
            default: values_body(1, 1, dh, used, vals + e0, sc, inv, o); break;
            }
        }
    }
}

static void attention(const Step *s, const Block *blk, const float *qkv, float *y, float *scores) {
    /* y [B * L, H * dh]; scores: QUERY_BLOCK * padded floats of scratch. Each head's keys and values are
       read once per QUERY_BLOCK queries. */
    int64_t H = s->heads, dh = s->d_head, S = s->slots, L = s->length, hd = H * dh, used = s->used;
    int64_t padded = (used + 15) / 16 * 16, blocks = (S + 15) / 16;
    for (int64_t b = 0; b < s->batch; b++)
        for (int64_t h = 0; h < H; h++) {
            const float *kb = blk->keys_blocked + (b * H + h) * blocks * dh * 16;
            const float *vals = blk->values + (b * H + h) * S * dh;
            for (int64_t i0 = 0; i0 < L; i0 += QUERY_BLOCK) {
                int64_t nq = L - i0 < QUERY_BLOCK ? L - i0 : QUERY_BLOCK;
                const float *q[QUERY_BLOCK], *mask[QUERY_BLOCK];
                float *sc[QUERY_BLOCK], *out[QUERY_BLOCK], inv[QUERY_BLOCK];
                for (int64_t i = 0; i < nq; i++) {
                    q[i] = qkv + (b * L + i0 + i) * 3 * hd + h * dh;
                    mask[i] = s->mask + b * s->mask_batch_stride + (i0 + i) * s->mask_row_stride;
                    sc[i] = scores + i * padded;
                    out[i] = y + (b * L + i0 + i) * hd + h * dh;
                }
                attention_scores(nq, dh, used, kb, q, mask, sc);
                for (int64_t i = 0; i < nq; i++) inv[i] = 1.0f / softmax_unnormalised(sc[i], padded);
                attention_values(nq, dh, used, vals, sc, inv, out);
            }
        }
}

/* ---- the step ---- */

int64_t navformer_step_scratch_floats(int64_t rows, int64_t d, int64_t heads, int64_t d_head, int64_t hidden,
                                      int64_t slots) {
    /* floats of Step.scratch for `rows` = B * L tokens */
    int64_t hd = heads * d_head;
    return rows * (2 * d + 3 * hd + hd + hidden) + QUERY_BLOCK * ((slots + 15) / 16 * 16);
}

void navformer_transformer_step(const Step *s) {
    int64_t M = s->batch * s->length, d = s->d, hd = s->heads * s->d_head;
    float *h = s->scratch, *t = h + M * d, *qkv = t + M * d, *y = qkv + M * 3 * hd, *f = y + M * hd;
    float *scores = f + M * s->hidden;
    memcpy(h, s->x, M * d * sizeof(float));
    for (int64_t i = 0; i < s->n_blocks; i++) {
        const Block *blk = s->blocks + i;
        layer_norm(h, t, M, d, blk->ln_attn_weight, blk->ln_attn_bias, blk->ln_attn_eps);
        gemm(M, 3 * hd, d, t, blk->qkv_weight, blk->qkv_bias, 0, qkv);
        write_cache(s, blk, qkv);
        attention(s, blk, qkv, y, scores);
        gemm(M, d, hd, y, blk->proj_weight, blk->proj_bias, h, h);
        layer_norm(h, t, M, d, blk->ln_mlp_weight, blk->ln_mlp_bias, blk->ln_mlp_eps);
        gemm(M, s->hidden, d, t, blk->fc_weight, blk->fc_bias, 0, f);
        gelu(f, M * s->hidden, s->gelu_tanh);
        gemm(M, d, s->hidden, f, blk->out_weight, blk->out_bias, h, h);
    }
    layer_norm(h, s->out, M, d, s->ln_final_weight, s->ln_final_bias, s->ln_final_eps);
}

/* ---- what the Python side checks at load time ---- */

int64_t navformer_step_abi(void) { return 1; }

int64_t navformer_step_struct_size(int64_t which) { return which == 0 ? (int64_t)sizeof(Step) : (int64_t)sizeof(Block); }
