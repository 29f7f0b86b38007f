/* CPU kernels for DreamerV3's categorical latents, compiled on first use by native.py.
 *
 * Each replaces a chain of PyTorch ops that passes over the same large tensor several times
 * (or an index_add per latent) with one pass. They compute what the PyTorch fallbacks in
 * latent.py / distributions.py compute; tests compare the two. Threads own disjoint outputs,
 * so results do not depend on scheduling.
 */
#include <math.h>
#include <stdint.h>
#include <string.h>
#ifdef _OPENMP
#include <omp.h>
#endif

#if defined(__x86_64__) && defined(__GLIBC__)
/* glibc's libmvec has vector versions of expf (and, since 2.35, tanhf) but math.h declares them
 * only under -ffast-math, whose other assumptions (no NaN) would hide a diverging model. */
float expf(float) __attribute__((__simd__("notinbranch")));
#if __GLIBC_PREREQ(2, 35)
float tanhf(float) __attribute__((__simd__("notinbranch")));
#endif
#endif

/* Gradient of an embedding-bag's table: out (rows x width) = sum over samples i and latents k
 * of grad[i] added to row index[i * stoch + k]. Each thread owns a block of latents, hence a
 * block of table rows (latent k's classes are rows k * classes ...), and walks the samples in
 * order: a gradient row is read once per thread and the summation order is fixed. */
void d2a_table_gradient(const int64_t *index, const float *grad, float *out, int64_t samples,
                        int64_t stoch, int64_t rows, int64_t width, int threads)
{
    memset(out, 0, sizeof(float) * (size_t)(rows * width));
    if (threads > stoch) threads = (int)stoch;
#pragma omp parallel num_threads(threads) if (threads > 1)
    {
        int t = 0, nt = 1;
#ifdef _OPENMP
        t = omp_get_thread_num();
        nt = omp_get_num_threads();
#endif
        const int64_t k0 = stoch * t / nt, k1 = stoch * (t + 1) / nt;
        for (int64_t i = 0; i < samples; i++) {
            const float *g = grad + i * width;
            const int64_t *idx = index + i * stoch;
            for (int64_t k = k0; k < k1; k++) {
                float *o = out + idx[k] * width;
#pragma omp simd
                for (int64_t c = 0; c < width; c++) o[c] += g[c];
            }
        }
    }
}

#define SAMPLE_BLOCK 8

/* For each of `groups` categoricals of `classes` logits (group g is latent g % stoch of its
 * sample), plus `bias` (stoch x classes) if not NULL: probs = (1 - mix) * softmax + mix / classes, and the inverse-CDF sample for
 * uniform[g]: the number of classes whose cumulative probability (summed in double, rounded to
 * float, as torch.cumsum) is below it, at most classes - 1 (torch.searchsorted, clamped).
 * index = class + (g % stoch) * classes. Groups are scanned SAMPLE_BLOCK at a time so that
 * their running sums, each a chain of dependent additions, overlap. */
void d2a_unimix_sample(const float *logits, const float *bias, const float *uniform, float *probs,
                       int64_t *index, int64_t groups, int64_t stoch, int64_t classes, float mix,
                       int threads)
{
    const float floor_prob = mix / (float)classes;
    const int64_t blocks = (groups + SAMPLE_BLOCK - 1) / SAMPLE_BLOCK;
#pragma omp parallel for num_threads(threads) schedule(static) if (threads > 1)
    for (int64_t b = 0; b < blocks; b++) {
        const int64_t g0 = b * SAMPLE_BLOCK;
        const int64_t count = groups - g0 < SAMPLE_BLOCK ? groups - g0 : SAMPLE_BLOCK;
        for (int64_t j = 0; j < count; j++) {
            const float *x = logits + (g0 + j) * classes;
            float *p = probs + (g0 + j) * classes;
            if (bias) {  /* p holds the biased logits until the exponent overwrites them */
                const float *add = bias + ((g0 + j) % stoch) * classes;
#pragma omp simd
                for (int64_t c = 0; c < classes; c++) p[c] = x[c] + add[c];
                x = p;
            }
            float top = x[0];
#pragma omp simd reduction(max : top)
            for (int64_t c = 0; c < classes; c++) top = x[c] > top ? x[c] : top;
            float total = 0.0f;
#pragma omp simd reduction(+ : total)
            for (int64_t c = 0; c < classes; c++) {
                p[c] = expf(x[c] - top);
                total += p[c];
            }
            const float scale = (1.0f - mix) / total;
#pragma omp simd
            for (int64_t c = 0; c < classes; c++) p[c] = p[c] * scale + floor_prob;
        }
        double cumulative[SAMPLE_BLOCK] = {0.0};
        int64_t below[SAMPLE_BLOCK] = {0};
        const float *p = probs + g0 * classes;
        for (int64_t c = 0; c < classes; c++) {
            for (int64_t j = 0; j < count; j++) {
                cumulative[j] += p[j * classes + c];
                below[j] += (float)cumulative[j] < uniform[g0 + j];
            }
        }
        for (int64_t j = 0; j < count; j++) {
            const int64_t pick = below[j] < classes ? below[j] : classes - 1;
            index[g0 + j] = pick + ((g0 + j) % stoch) * classes;
        }
    }
}
/* Gradient of the logits given the gradient of d2a_unimix_sample's probs: with
 * q = probs - mix / classes = (1 - mix) * softmax, d logits = q * (grad - sum(q * grad) / (1 - mix)). */
void d2a_unimix_backward(const float *probs, const float *grad, float *out, int64_t groups,
                         int64_t classes, float mix, int threads)
{
    const float floor_prob = mix / (float)classes;
    const float inverse = 1.0f / (1.0f - mix);
#pragma omp parallel for num_threads(threads) schedule(static) if (threads > 1)
    for (int64_t g = 0; g < groups; g++) {
        const float *p = probs + g * classes;
        const float *d = grad + g * classes;
        float *o = out + g * classes;
        float dot = 0.0f;
#pragma omp simd reduction(+ : dot)
        for (int64_t c = 0; c < classes; c++) dot += (p[c] - floor_prob) * d[c];
        dot *= inverse;
#pragma omp simd
        for (int64_t c = 0; c < classes; c++) o[c] = (p[c] - floor_prob) * (d[c] - dot);
    }
}

static inline float sigmoid(float x) { return 1.0f / (1.0f + expf(-x)); }

/* DreamerV3's LayerNorm GRU cell after its matmul: q = LayerNorm(p) * weight + bias over the
 * 3 * deter columns of each row of p (reset, candidate, update parts), reset = sigmoid(q_r),
 * candidate = tanh(reset * q_c), update = sigmoid(q_u - 1), h = h_prev + update * (candidate - h_prev).
 * Writes h and each row's mean and 1 / std for the backward pass. */
void d2a_ln_gru(const float *p, const float *h_prev, const float *weight, const float *bias,
                float eps, float *h, float *mean_out, float *rstd_out, int64_t rows, int64_t deter,
                int threads)
{
    const int64_t width = 3 * deter;
#pragma omp parallel for num_threads(threads) schedule(static) if (threads > 1)
    for (int64_t i = 0; i < rows; i++) {
        const float *x = p + i * width;
        const float *hp = h_prev + i * deter;
        float *out = h + i * deter;
        float sum = 0.0f, squares = 0.0f;
#pragma omp simd reduction(+ : sum)
        for (int64_t j = 0; j < width; j++) sum += x[j];
        const float mean = sum / (float)width;
#pragma omp simd reduction(+ : squares)
        for (int64_t j = 0; j < width; j++) squares += (x[j] - mean) * (x[j] - mean);
        const float rstd = 1.0f / sqrtf(squares / (float)width + eps);
        mean_out[i] = mean;
        rstd_out[i] = rstd;
        const int64_t c = deter, u = 2 * deter;
#pragma omp simd
        for (int64_t j = 0; j < deter; j++) {
            const float reset = sigmoid((x[j] - mean) * rstd * weight[j] + bias[j]);
            const float cand = (x[c + j] - mean) * rstd * weight[c + j] + bias[c + j];
            const float update = sigmoid((x[u + j] - mean) * rstd * weight[u + j] + bias[u + j] - 1.0f);
            const float next = tanhf(reset * cand);
            out[j] = hp[j] + update * (next - hp[j]);
        }
    }
}

/* Backward of d2a_ln_gru given dh: writes dp (gradient of the cell's input p), dh_prev and, if
 * dq is not NULL, the gradient of the norm's output q (for the weight and bias gradients). */
void d2a_ln_gru_backward(const float *p, const float *h_prev, const float *weight,
                         const float *bias, const float *mean_in, const float *rstd_in,
                         const float *dh, float *dp, float *dh_prev, float *dq, int64_t rows,
                         int64_t deter, int threads)
{
    const int64_t width = 3 * deter;
#pragma omp parallel for num_threads(threads) schedule(static) if (threads > 1)
    for (int64_t i = 0; i < rows; i++) {
        const float *x = p + i * width;
        const float *hp = h_prev + i * deter;
        const float *g = dh + i * deter;
        float *dx = dp + i * width;  /* holds weight * dq until the norm's backward below */
        float *dhp = dh_prev + i * deter;
        float *dqi = dq ? dq + i * width : 0;
        const float mean = mean_in[i], rstd = rstd_in[i];
        const int64_t c = deter, u = 2 * deter;
        /* The gates are recomputed as in d2a_ln_gru (written out: a helper returning them kept
         * GCC from vectorising either loop). */
#pragma omp simd
        for (int64_t j = 0; j < deter; j++) {
            const float reset = sigmoid((x[j] - mean) * rstd * weight[j] + bias[j]);
            const float cand = (x[c + j] - mean) * rstd * weight[c + j] + bias[c + j];
            const float update = sigmoid((x[u + j] - mean) * rstd * weight[u + j] + bias[u + j] - 1.0f);
            const float next = tanhf(reset * cand);
            const float dnext = g[j] * update;
            const float dupdate = g[j] * (next - hp[j]);
            dhp[j] = g[j] - dnext;
            const float dinner = dnext * (1.0f - next * next);
            const float dq_r = dinner * cand * reset * (1.0f - reset);
            const float dq_c = dinner * reset;
            const float dq_u = dupdate * update * (1.0f - update);
            if (dqi) {
                dqi[j] = dq_r;
                dqi[c + j] = dq_c;
                dqi[u + j] = dq_u;
            }
            dx[j] = dq_r * weight[j];
            dx[c + j] = dq_c * weight[c + j];
            dx[u + j] = dq_u * weight[u + j];
        }
        float total = 0.0f, projected = 0.0f;
#pragma omp simd reduction(+ : total, projected)
        for (int64_t j = 0; j < width; j++) {
            total += dx[j];
            projected += dx[j] * (x[j] - mean) * rstd;
        }
        total /= (float)width;
        projected /= (float)width;
#pragma omp simd
        for (int64_t j = 0; j < width; j++) dx[j] = rstd * (dx[j] - total - (x[j] - mean) * rstd * projected);
    }
}
