// The C example's rollout and linearisation through the RAII wrapper, printed the same way.
//   c++ -std=c++17 -O2 example.cpp -I. -I../../include -L../../target/release -l:libpinc_c.a -lm -lpthread -ldl -lgcc_s
#include <cmath>
#include <cstdio>

#include "pinc.hpp"

static void print_row(const char *tag, size_t k, const double *v, int len) {
    std::printf("%s %zu", tag, k);
    for (int i = 0; i < len; i++) std::printf(" %.17g", v[i]);
    std::printf("\n");
}

int main(int argc, char **argv) {
    if (argc != 2) {
        std::fprintf(stderr, "usage: %s MODEL.pinc\n", argv[0]);
        return 2;
    }
    try {
        pinc::Predictor p(argv[1]);
        pinc::Workspace w(p);
        pinc::State x0{0.0, 0.0, 1.0, std::cos(0.5), std::sin(0.5), 0.3, 0.0, 0.05, 0.0};
        std::vector<pinc::Input> u(20);
        for (size_t k = 0; k < u.size(); k++) u[k] = {4.0 * std::sin(0.3 * k), 0.5, 3.0 + 0.1 * k, 0.2 * std::cos(0.2 * k)};
        std::printf("dt %.17g\n", p.dt());
        auto traj = w.rollout(x0, u);
        for (size_t k = 0; k < traj.size(); k++) print_row("rollout", k, traj[k].data(), 9);
        auto lin = w.linearise(x0, u);
        for (size_t k = 0; k < lin.trajectory.size(); k++) print_row("traj", k, lin.trajectory[k].data(), 9);
        for (size_t k = 0; k < lin.a.size(); k++) print_row("a", k, lin.a[k].data(), 81);
        for (size_t k = 0; k < lin.b.size(); k++) print_row("b", k, lin.b[k].data(), 36);
        std::printf("exits %d\n", w.envelope_exits());
        try {
            pinc::State bad = x0;
            bad[2] = NAN;
            w.step(bad, u[0]);
        } catch (const pinc::Error &e) {
            std::printf("nan_state %d %s\n", e.code(), e.what());
        }
        try {
            pinc::Predictor missing("no/such/model.pinc");
        } catch (const pinc::Error &e) {
            std::printf("missing_file %d %s\n", e.code(), e.what());
        }
    } catch (const pinc::Error &e) {
        std::fprintf(stderr, "error %d: %s\n", e.code(), e.what());
        return 1;
    }
    return 0;
}
