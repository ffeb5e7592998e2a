/* Loads a model, rolls out 20 steps, linearises the horizon and shows an error, printing
 * every number with 17 significant digits (exact for doubles) so that a test can compare
 * them with the Rust API bit for bit.
 *
 *   cc -O2 example.c -I../../include -L../../target/release -l:libpinc_c.a -lm -lpthread -ldl -lgcc_s
 *   ./a.out ../../models/mpc_pinc_thrust.pinc
 */
#include <math.h>
#include <stdio.h>
#include "pinc.h"

#define N 20

static void print_row(const char *tag, int k, const double *v, int len) {
    printf("%s %d", tag, k);
    for (int i = 0; i < len; i++) printf(" %.17g", v[i]);
    printf("\n");
}

int main(int argc, char **argv) {
    if (argc != 2) {
        fprintf(stderr, "usage: %s MODEL.pinc\n", argv[0]);
        return 2;
    }
    PincPredictor *p = NULL;
    PincWorkspace *w = NULL;
    if (pinc_predictor_load(argv[1], &p) != PINC_OK || pinc_workspace_new(p, &w) != PINC_OK) {
        fprintf(stderr, "error: %s\n", pinc_last_error());
        pinc_predictor_free(p);
        return 1;
    }
    /* Heading 0.5 rad, moving forward, under a slowly turning input. */
    double x0[9] = {0.0, 0.0, 1.0, cos(0.5), sin(0.5), 0.3, 0.0, 0.05, 0.0};
    double u[N * 4], traj[(N + 1) * 9], a[N * 81], b[N * 36];
    for (int k = 0; k < N; k++) {
        u[4 * k + 0] = 4.0 * sin(0.3 * k);
        u[4 * k + 1] = 0.5;
        u[4 * k + 2] = 3.0 + 0.1 * k;
        u[4 * k + 3] = 0.2 * cos(0.2 * k);
    }
    printf("dt %.17g\n", pinc_predictor_dt(p));

    int rc = pinc_rollout(p, w, x0, u, N, traj);
    if (rc != PINC_OK) fprintf(stderr, "rollout: %d %s\n", rc, pinc_last_error());
    for (int k = 0; k <= N; k++) print_row("rollout", k, traj + 9 * k, 9);

    rc = pinc_linearise_horizon(p, w, x0, u, N, traj, a, b);
    if (rc != PINC_OK) fprintf(stderr, "linearise: %d %s\n", rc, pinc_last_error());
    for (int k = 0; k <= N; k++) print_row("traj", k, traj + 9 * k, 9);
    for (int k = 0; k < N; k++) print_row("a", k, a + 81 * k, 81);
    for (int k = 0; k < N; k++) print_row("b", k, b + 36 * k, 36);
    printf("exits %d\n", pinc_envelope_exits(w));

    double next[9], bad[9] = {0.0, 0.0, NAN, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0};
    rc = pinc_step(p, w, bad, u, 0.0, next);
    printf("nan_state %d %s\n", rc, pinc_last_error());
    rc = pinc_step(p, NULL, x0, u, 0.0, next);
    printf("null_workspace %d %s\n", rc, pinc_last_error());

    pinc_workspace_free(w);
    pinc_predictor_free(p);
    return 0;
}
