/* The data kernel's inner loop in plain C, to see how close jaxpose's XLA-compiled
 * kernel comes to what a C compiler makes of the same arithmetic on one core.
 *
 * Per individual and block of 256 points: for every point, the distance to the
 * surface of each of L capsules (clamped projection on the segment, |d - r|) with a
 * running minimum over the links, as jaxpose.objective._link_scan computes it, then
 * the sum over the block of log(1 + d / sigma) of the nearest distances (built with
 * -DNO_LOG, the sum of the distances instead).  Random capsules and points; the sum
 * is printed only so that the compiler cannot drop the work.
 *
 *   gcc -O3 -march=native -ffast-math -o distance_loop distance_loop.c -lm
 *   taskset -c 0 ./distance_loop          # one core
 *   gcc -O3 -march=native -ffast-math -DNO_LOG -o distance_loop distance_loop.c -lm
 *
 * Compare with the kernel pinned to the same core (docs/performance.md, "How close
 * the kernel is to the machine").
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#define L 17    /* links (the humanoid) */
#define P 1024  /* individuals */
#define N 2048  /* points */
#define BS 256  /* points per block, as ObjectiveConfig.block */

static float px[N], py[N], pz[N];
static float A[P][L][3], U[P][L][3], IV[P][L], C[P][L], R[P][L];
static float best[BS];

static float uniform(void) { return rand() / (float)RAND_MAX; }

int main(void) {
    srand(1);
    for (int i = 0; i < N; i++) {
        px[i] = uniform();
        py[i] = uniform();
        pz[i] = 2.0f + uniform();
    }
    for (int p = 0; p < P; p++)
        for (int l = 0; l < L; l++) {
            float uu = 0.0f, au = 0.0f;
            for (int c = 0; c < 3; c++) {
                A[p][l][c] = uniform();
                U[p][l][c] = 0.3f * uniform();
                uu += U[p][l][c] * U[p][l][c];
                au += A[p][l][c] * U[p][l][c];
            }
            IV[p][l] = 1.0f / uu; /* 1 / |b - a|^2 */
            C[p][l] = au;         /* a . (b - a) */
            R[p][l] = 0.05f;
        }
    double total = 0.0;
    const int reps = 10;
    struct timespec t0, t1;
    clock_gettime(CLOCK_MONOTONIC, &t0);
    for (int rep = 0; rep < reps; rep++)
        for (int b0 = 0; b0 < N; b0 += BS)
            for (int p = 0; p < P; p++) {
                float ax[L], ay[L], az[L], ux[L], uy[L], uz[L], iv[L], c[L], r[L];
                for (int l = 0; l < L; l++) {
                    ax[l] = A[p][l][0], ay[l] = A[p][l][1], az[l] = A[p][l][2];
                    ux[l] = U[p][l][0], uy[l] = U[p][l][1], uz[l] = U[p][l][2];
                    iv[l] = IV[p][l], c[l] = C[p][l], r[l] = R[p][l];
                }
                for (int i = 0; i < BS; i++) {
                    float x = px[b0 + i], y = py[b0 + i], z = pz[b0 + i], m = INFINITY;
                    for (int l = 0; l < L; l++) {
                        float t = (x * ux[l] + y * uy[l] + z * uz[l] - c[l]) * iv[l];
                        t = t < 0.0f ? 0.0f : (t > 1.0f ? 1.0f : t);
                        float dx = x - ax[l] - t * ux[l], dy = y - ay[l] - t * uy[l], dz = z - az[l] - t * uz[l];
                        float d = fabsf(sqrtf(dx * dx + dy * dy + dz * dz) - r[l]);
                        m = d < m ? d : m;
                    }
                    best[i] = m;
                }
                float s = 0.0f;
#ifdef NO_LOG
                for (int i = 0; i < BS; i++) s += best[i];
#else
                for (int i = 0; i < BS; i++) s += logf(1.0f + best[i] * 2.0f); /* sigma 0.5 */
#endif
                total += s;
            }
    clock_gettime(CLOCK_MONOTONIC, &t1);
    double sec = (t1.tv_sec - t0.tv_sec) + 1e-9 * (t1.tv_nsec - t0.tv_nsec);
#ifdef NO_LOG
    const char *what = "no log";
#else
    const char *what = "with the log";
#endif
    printf("%.2f G point-to-capsule distances/s (P=%d, N=%d, L=%d, %s; checksum %g)\n",
           (double)reps * P * N * L / sec / 1e9, P, N, L, what, total);
    return 0;
}
