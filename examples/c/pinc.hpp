// A small C++17 RAII wrapper over include/pinc.h: the handles are freed by destructors, and
// a failing call throws pinc::Error with the library's message and code.
#pragma once

#include <array>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "pinc.h"

namespace pinc {

using State = std::array<double, 9>;  // [x, y, z, cos psi, sin psi, u, v, w, r]
using Input = std::array<double, 4>;  // [X, Y, Z, Mz]

class Error : public std::runtime_error {
  public:
    Error(int code, const std::string &what) : std::runtime_error(what), code_(code) {}
    int code() const { return code_; }

  private:
    int code_;
};

inline void check(int rc) {
    if (rc != PINC_OK) throw Error(rc, pinc_last_error());
}

// The frozen model: immutable, shareable between threads.
class Predictor {
  public:
    explicit Predictor(const std::string &path) { check(pinc_predictor_load(path.c_str(), &p_)); }
    Predictor(const Predictor &) = delete;
    Predictor &operator=(const Predictor &) = delete;
    Predictor(Predictor &&o) noexcept : p_(std::exchange(o.p_, nullptr)) {}
    ~Predictor() { pinc_predictor_free(p_); }

    double dt() const { return pinc_predictor_dt(p_); }
    const PincPredictor *get() const { return p_; }

  private:
    PincPredictor *p_ = nullptr;
};

// The horizon's trajectory and row-major Jacobians.
struct Linearisation {
    std::vector<State> trajectory;                   // n + 1
    std::vector<std::array<double, 81>> a;           // n, d x_{k+1} / d x_k
    std::vector<std::array<double, 36>> b;           // n, d x_{k+1} / d u_k
};

// One thread's scratch memory, tied to its predictor; no call allocates but the vectors
// the convenience methods return.
class Workspace {
  public:
    explicit Workspace(const Predictor &p) : p_(p.get()) { check(pinc_workspace_new(p_, &w_)); }
    Workspace(const Workspace &) = delete;
    Workspace &operator=(const Workspace &) = delete;
    ~Workspace() { pinc_workspace_free(w_); }

    State step(const State &x, const Input &u, double dt = 0.0) {
        State out;
        check(pinc_step(p_, w_, x.data(), u.data(), dt, out.data()));
        return out;
    }

    std::vector<State> rollout(const State &x0, const std::vector<Input> &u) {
        std::vector<State> traj(u.size() + 1);
        check(pinc_rollout(p_, w_, x0.data(), u.front().data(), u.size(), traj.front().data()));
        return traj;
    }

    Linearisation linearise(const State &x0, const std::vector<Input> &u) {
        Linearisation l{std::vector<State>(u.size() + 1), std::vector<std::array<double, 81>>(u.size()),
                        std::vector<std::array<double, 36>>(u.size())};
        check(pinc_linearise_horizon(p_, w_, x0.data(), u.front().data(), u.size(), l.trajectory.front().data(),
                                     l.a.front().data(), l.b.front().data()));
        return l;
    }

    int envelope_exits() const { return pinc_envelope_exits(w_); }

  private:
    const PincPredictor *p_;
    PincWorkspace *w_ = nullptr;
};

}  // namespace pinc
