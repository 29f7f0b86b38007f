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
/* glibc's libmvec has vector versions of expf but math.h declares them only under -ffast-math,
 * whose other assumptions (no NaN) would hide a diverging model. */
float expf(float) __attribute__((__simd__("notinbranch")));
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
