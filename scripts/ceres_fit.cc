// A per-texel Ceres solver for scripts/bench_fit.py: the baseline a performance-minded C++ user would write
// for relight.fit(model="ggx", normals=True, loss="cauchy") (issue 30, item 3).
//
// The problem is bench_fit.py's numpy reference (np_predict / np_residual), term for term, so that the
// benchmark can hold the two costs to each other: 7 unconstrained parameters per texel
//   u = logit rho_d[3], logit F0, logit((alpha - floor) / (1 - floor)), a, b   (normal = (a, b, 1) / |.|)
// and per valid observation and channel the residual pred - obs with
//   pred = (rho_d / pi + D F G1(wi) G1(wo) / (4 cos_i cos_o)) cos_i irr        (0 unless cos_i, cos_o > 0)
// in the fitted frame (t = surface tangent (1, 0, 0) projected off n, b = n x t): GGX D (Walter et al. 2007,
// eq. 33), separable Smith G1 (eq. 34), Schlick's F. The loss is Cauchy with the texel's scale c:
//   "sqrt"   (default): the residual r sqrt(log1p(y) / y), y = (r / c)^2, as numpy and relight write it (Triggs
//            et al. 2000's square-rooted robust residual, its exact Jacobian by automatic differentiation);
//   "cauchy": the plain residual under ceres::CauchyLoss(c) (Ceres's corrected Gauss-Newton model of the same
//            cost c^2 log(1 + (r / c)^2)); Ceres applies a loss to a block's squared norm, so this takes one
//            residual block per observation and channel (the idiomatic Ceres problem, 3x the model work).
// Both give Ceres's cost 0.5 sum c^2 log(1 + (r / c)^2), the numpy reference's 0.5 sum np_residual^2.
//
// Derivatives (--jacobian): "autodiff", ceres::AutoDiffCostFunction (dual numbers, Jet<double, 7>), one residual
// block per texel holding all its observations (3 residuals each), so the fitted frame is built once per
// evaluation; or "structured" (StructuredTexelCost): the albedo columns in closed form, dual numbers over the
// 4 other parameters only, as relight's residual_and_jacobian does. Solver:
// Levenberg-Marquardt with a dense QR (or normal-equations Cholesky) of the 7-column Jacobian, at most
// --max-iterations steps or until Ceres's convergence tests (function, gradient, parameter tolerances) stop it.
// Texels are independent problems, so the threads take texels from a shared counter (one ceres::Problem each);
// Ceres's own num_threads would parallelise inside one 7-parameter problem, where there is nothing to share.
//
// Input, in the folder given as the first argument (raw little-endian files written by scripts/_ceres.py):
//   offsets.i64 [n + 1]: texel p's valid observations are rows offsets[p] .. offsets[p + 1] - 1 of
//   obs.f64, wi.f64, wo.f64, irr.f64 [M, 3]: radiance, unit directions to the light and the camera in the
//       texel's surface frame, irradiance at normal incidence (the mask is applied: only valid observations);
//   start.f64 [n, 7]: the start u0 (relight.fitting.start_parameters);  scale.f64 [n]: the Cauchy scale c.
// Output, in the same folder: solution.f64 [n, 7]; stats.f64 [n, 8] = (cost at the start, cost at the solution,
// iterations, 1 if Ceres reported convergence else 0, and Ceres's own seconds: the whole Solve, Jacobian
// evaluations, residual evaluations, linear solves); and one JSON line on stdout with the timings (the solve
// alone and its process CPU time, and reading / writing the files), measured with std::chrono's steady clock.
//
// Build (scripts/_ceres.py does it): g++ -O3 -march=native -std=c++17 -DNDEBUG ceres_fit.cc
//   -I/usr/include/eigen3 -lceres -lglog -lpthread   (Debian: apt-get install libceres-dev)

#include <ceres/ceres.h>
#include <ceres/version.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <fstream>
#include <string>
#include <thread>
#include <vector>

namespace {

constexpr int kParams = 7;
constexpr int kStats = 8;  // per texel: see stats.f64 above

template <typename V>
std::vector<V> read_raw(const std::string& path) {
  std::ifstream f(path, std::ios::binary | std::ios::ate);
  if (!f) {
    std::fprintf(stderr, "ceres_fit: cannot read %s\n", path.c_str());
    std::exit(2);
  }
  const std::streamsize bytes = f.tellg();
  std::vector<V> out(static_cast<size_t>(bytes) / sizeof(V));
  f.seekg(0);
  f.read(reinterpret_cast<char*>(out.data()), static_cast<std::streamsize>(out.size() * sizeof(V)));
  return out;
}

template <typename V>
void write_raw(const std::string& path, const std::vector<V>& v) {
  std::ofstream f(path, std::ios::binary);
  f.write(reinterpret_cast<const char*>(v.data()), static_cast<std::streamsize>(v.size() * sizeof(V)));
  if (!f) {
    std::fprintf(stderr, "ceres_fit: cannot write %s\n", path.c_str());
    std::exit(2);
  }
}

template <typename T>
T sigmoid(const T& x) {
  return T(1.0) / (T(1.0) + exp(-x));
}

// The square-rooted Cauchy residual of res with scale c, smooth at 0 (relight's cauchy_scale); c <= 0: res.
template <typename T>
T robust(const T& res, double c) {
  using std::sqrt;
  if (c <= 0.0) return res;
  const T y = (res / c) * (res / c);
  return y < 1e-6 ? res * (T(1.0) - T(0.25) * y) : res * sqrt(log1p(y) / y);
}

// The model's non-diffuse part from q = u[3..6] (logit F0, logit alpha, the normal's a, b): the fitted frame
// (rows t, b, n: np_predict's R) built once, then per observation the specular lobe and cos_i.
template <typename T>
struct Lobe {
  T f0, a2, t[3], b[3], n[3];

  Lobe(const T* q, double floor) {
    using std::sqrt;
    f0 = sigmoid(q[0]);
    const T al = T(floor) + T(1.0 - floor) * sigmoid(q[1]);
    a2 = al * al;
    const T nlen = sqrt(q[2] * q[2] + q[3] * q[3] + T(1.0));
    n[0] = q[2] / nlen, n[1] = q[3] / nlen, n[2] = T(1.0) / nlen;
    const T t0[3] = {T(1.0) - n[0] * n[0], -n[0] * n[1], -n[0] * n[2]};
    const T tlen = sqrt(t0[0] * t0[0] + t0[1] * t0[1] + t0[2] * t0[2]);
    for (int j = 0; j < 3; ++j) t[j] = t0[j] / tlen;
    b[0] = n[1] * t[2] - n[2] * t[1], b[1] = n[2] * t[0] - n[0] * t[2], b[2] = n[0] * t[1] - n[1] * t[0];
  }

  // wi, wo: one observation's unit directions in the surface frame. spec: D F G1(wi) G1(wo) / (4 cos_i cos_o)
  // (0 unless lit and the half vector is above the horizon); cos_i: 0 unless lit (cos_i, cos_o > 0).
  void operator()(const double* wi, const double* wo, T& spec, T& cos_i) const {
    using std::sqrt;
    const T xi = t[0] * wi[0] + t[1] * wi[1] + t[2] * wi[2];
    const T yi = b[0] * wi[0] + b[1] * wi[1] + b[2] * wi[2];
    const T zi = n[0] * wi[0] + n[1] * wi[1] + n[2] * wi[2];
    const T xo = t[0] * wo[0] + t[1] * wo[1] + t[2] * wo[2];
    const T yo = b[0] * wo[0] + b[1] * wo[1] + b[2] * wo[2];
    const T zo = n[0] * wo[0] + n[1] * wo[1] + n[2] * wo[2];
    spec = T(0.0);
    cos_i = T(0.0);
    if (!(zi > 0.0 && zo > 0.0)) return;
    cos_i = zi;
    T hx = xi + xo, hy = yi + yo, hz = zi + zo;
    T hlen = sqrt(hx * hx + hy * hy + hz * hz);
    if (hlen < 1e-12) hlen = T(1e-12);
    hx /= hlen, hy /= hlen, hz /= hlen;
    if (!(hz > 0.0)) return;
    const T tD = (hx * hx + hy * hy) / a2 + hz * hz;
    const T D = T(1.0) / (T(M_PI) * a2 * tD * tD);  // GGX D (Walter et al. 2007, eq. 33)
    T cos_h = xi * hx + yi * hy + zi * hz;          // clipped to [0, 1], as np.clip
    if (cos_h < 0.0) cos_h = T(0.0);
    if (cos_h > 1.0) cos_h = T(1.0);
    const T q = T(1.0) - cos_h, q2 = q * q;
    const T F = f0 + (T(1.0) - f0) * q2 * q2 * q;  // Schlick
    // Separable Smith G1 / cos (Walter et al. 2007, eq. 34).
    const T g1i = T(2.0) / (zi + sqrt(a2 * (xi * xi + yi * yi) + zi * zi));
    const T g1o = T(2.0) / (zo + sqrt(a2 * (xo * xo + yo * yo) + zo * zo));
    spec = D * F * T(0.25) * g1i * g1o;
  }
};

// One texel's residuals for ceres::AutoDiffCostFunction: m observations x 3 channels, in bench_fit.py's
// np_residual order (observation-major), pred = (rho_d / pi + spec) cos_i irr.
struct TexelResidual {
  const double* obs;  // [m, 3]
  const double* wi;   // [m, 3]
  const double* wo;   // [m, 3]
  const double* irr;  // [m, 3]
  int m;
  double floor;  // the rig's smallest roughness (relight.rig_alpha_floor)
  double c;      // Cauchy scale (radiance units); <= 0: plain residual (ceres::CauchyLoss then applies it)
  int channel;   // -1: all three channels (3 m residuals); 0, 1, 2: that channel only (m residuals)

  template <typename T>
  bool operator()(const T* const u, T* r) const {
    const T rho[3] = {sigmoid(u[0]), sigmoid(u[1]), sigmoid(u[2])};
    const Lobe<T> lobe(u + 3, floor);
    for (int k = 0; k < m; ++k) {
      T spec, cos_i;
      lobe(wi + 3 * k, wo + 3 * k, spec, cos_i);
      for (int ch = 0; ch < 3; ++ch) {
        if (channel >= 0 && ch != channel) continue;
        *r++ = robust((rho[ch] * (1.0 / M_PI) + spec) * cos_i * irr[3 * k + ch] - obs[3 * k + ch], c);
      }
    }
    return true;
  }
};

// The same residuals with a structured Jacobian (what relight's residual_and_jacobian does): pred_c depends on
// u_c (c < 3) only through rho_c / pi, a closed-form column; only spec and cos_i carry dual numbers, over the
// 4 parameters u[3..6] instead of 7. What a performance-minded user writes after profiling the autodiff one.
class StructuredTexelCost final : public ceres::CostFunction {
 public:
  explicit StructuredTexelCost(const TexelResidual& d) : d_(d) {
    set_num_residuals(3 * d.m);
    mutable_parameter_block_sizes()->push_back(kParams);
  }

  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override {
    const double* u = parameters[0];
    if (jacobians == nullptr || jacobians[0] == nullptr) return d_(u, residuals);
    using J4 = ceres::Jet<double, 4>;
    using J1 = ceres::Jet<double, 1>;
    const J4 q[4] = {J4(u[3], 0), J4(u[4], 1), J4(u[5], 2), J4(u[6], 3)};
    const Lobe<J4> lobe(q, d_.floor);
    double rho[3], drho[3];
    for (int ch = 0; ch < 3; ++ch) rho[ch] = sigmoid(u[ch]), drho[ch] = rho[ch] * (1.0 - rho[ch]) / M_PI;
    double* J = jacobians[0];  // row-major [3 m, 7]
    for (int k = 0; k < d_.m; ++k) {
      J4 spec, cos_i;
      lobe(d_.wi + 3 * k, d_.wo + 3 * k, spec, cos_i);
      for (int ch = 0; ch < 3; ++ch, J += kParams) {
        const double irr = d_.irr[3 * k + ch], base = rho[ch] / M_PI + spec.a;
        const J1 r = robust(J1(base * cos_i.a * irr - d_.obs[3 * k + ch], 0), d_.c);  // dr / d pred
        *residuals++ = r.a;
        const double g = r.v[0] * irr;
        J[0] = J[1] = J[2] = 0.0;
        J[ch] = g * drho[ch] * cos_i.a;
        for (int j = 0; j < 4; ++j) J[3 + j] = g * (spec.v[j] * cos_i.a + base * cos_i.v[j]);
      }
    }
    return true;
  }

 private:
  TexelResidual d_;
};

struct Settings {
  std::string loss = "sqrt";
  bool structured = false;  // --jacobian structured: StructuredTexelCost (loss sqrt only)
  ceres::LinearSolverType linear = ceres::DENSE_QR;
  int max_iterations = 60;
  // The scipy loop's ftol and xtol (1e-8); Ceres's default gradient tolerance.
  double function_tolerance = 1e-8, parameter_tolerance = 1e-8, gradient_tolerance = 1e-10;
  int threads = 0;
  double floor = 0.0;
};

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// CPU seconds of the whole process, every thread (what a shared machine's other users do not inflate).
double cpu_seconds() {
  timespec ts{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 3) {
    std::fprintf(stderr,
                 "usage: ceres_fit DIR FLOOR [--loss sqrt|cauchy] [--linear qr|cholesky] [--jacobian autodiff|structured]\n"
                 "                 [--max-iterations N] [--ftol X] [--xtol X] [--gtol X] [--threads N]\n");
    return 2;
  }
  const std::string dir = argv[1];
  Settings s;
  s.floor = std::atof(argv[2]);
  for (int i = 3; i + 1 < argc; i += 2) {
    const std::string key = argv[i], val = argv[i + 1];
    if (key == "--loss") s.loss = val;
    else if (key == "--linear") s.linear = val == "cholesky" ? ceres::DENSE_NORMAL_CHOLESKY : ceres::DENSE_QR;
    else if (key == "--jacobian") s.structured = val == "structured";
    else if (key == "--max-iterations") s.max_iterations = std::atoi(val.c_str());
    else if (key == "--ftol") s.function_tolerance = std::atof(val.c_str());
    else if (key == "--xtol") s.parameter_tolerance = std::atof(val.c_str());
    else if (key == "--gtol") s.gradient_tolerance = std::atof(val.c_str());
    else if (key == "--threads") s.threads = std::atoi(val.c_str());
    else {
      std::fprintf(stderr, "ceres_fit: unknown option %s\n", key.c_str());
      return 2;
    }
  }
  if (s.loss != "sqrt" && s.loss != "cauchy") {
    std::fprintf(stderr, "ceres_fit: --loss is sqrt or cauchy, got %s\n", s.loss.c_str());
    return 2;
  }
  if (s.threads <= 0) s.threads = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));

  auto t_read = std::chrono::steady_clock::now();
  const auto offsets = read_raw<int64_t>(dir + "/offsets.i64");
  const auto obs = read_raw<double>(dir + "/obs.f64");
  const auto wi = read_raw<double>(dir + "/wi.f64");
  const auto wo = read_raw<double>(dir + "/wo.f64");
  const auto irr = read_raw<double>(dir + "/irr.f64");
  const auto start = read_raw<double>(dir + "/start.f64");
  const auto scale = read_raw<double>(dir + "/scale.f64");
  const double read_s = seconds_since(t_read);
  const int64_t n = static_cast<int64_t>(offsets.size()) - 1;
  if (n < 0 || static_cast<int64_t>(start.size()) != n * kParams || static_cast<int64_t>(scale.size()) != n ||
      static_cast<int64_t>(obs.size()) != 3 * offsets.back()) {
    std::fprintf(stderr, "ceres_fit: inconsistent input sizes in %s\n", dir.c_str());
    return 2;
  }

  std::vector<double> solution(start);
  std::vector<double> stats(static_cast<size_t>(kStats * n));
  std::atomic<int64_t> next{0};
  auto worker = [&]() {
    ceres::Solver::Options opt;
    opt.minimizer_type = ceres::TRUST_REGION;
    opt.trust_region_strategy_type = ceres::LEVENBERG_MARQUARDT;
    opt.linear_solver_type = s.linear;
    opt.max_num_iterations = s.max_iterations;
    opt.function_tolerance = s.function_tolerance;
    opt.parameter_tolerance = s.parameter_tolerance;
    opt.gradient_tolerance = s.gradient_tolerance;
    opt.num_threads = 1;
    opt.logging_type = ceres::SILENT;
    opt.minimizer_progress_to_stdout = false;
    for (int64_t p; (p = next.fetch_add(1)) < n;) {
      const int64_t o0 = offsets[p], m = offsets[p + 1] - o0;
      double* x = solution.data() + kParams * p;
      double* st = stats.data() + kStats * p;
      if (m == 0) {  // no valid observation: the start stands (scipy has nothing to fit either)
        std::fill(st, st + kStats, 0.0);
        continue;
      }
      ceres::Problem problem;
      const TexelResidual all{obs.data() + 3 * o0, wi.data() + 3 * o0, wo.data() + 3 * o0, irr.data() + 3 * o0,
                              static_cast<int>(m), s.floor, scale[p], -1};
      if (s.loss == "sqrt" && s.structured) {
        problem.AddResidualBlock(new StructuredTexelCost(all), nullptr, x);
      } else if (s.loss == "sqrt") {  // one block: every observation and channel, the robust residual inside
        problem.AddResidualBlock(new ceres::AutoDiffCostFunction<TexelResidual, ceres::DYNAMIC, kParams>(
                                     new TexelResidual(all), static_cast<int>(3 * m)),
                                 nullptr, x);
      } else {  // Ceres's loss applies to a block's squared norm: one block per observation and channel
        for (int64_t k = o0; k < o0 + m; ++k)
          for (int ch = 0; ch < 3; ++ch)
            problem.AddResidualBlock(new ceres::AutoDiffCostFunction<TexelResidual, 1, kParams>(new TexelResidual{
                                         obs.data() + 3 * k, wi.data() + 3 * k, wo.data() + 3 * k, irr.data() + 3 * k,
                                         1, s.floor, 0.0, ch}),
                                     new ceres::CauchyLoss(scale[p]), x);
      }
      ceres::Solver::Summary summary;
      ceres::Solve(opt, &problem, &summary);
      st[0] = summary.initial_cost;
      st[1] = summary.final_cost;
      st[2] = static_cast<double>(summary.iterations.size() > 0 ? summary.iterations.size() - 1 : 0);
      st[3] = summary.termination_type == ceres::CONVERGENCE ? 1.0 : 0.0;
      st[4] = summary.total_time_in_seconds;
      st[5] = summary.jacobian_evaluation_time_in_seconds;
      st[6] = summary.residual_evaluation_time_in_seconds;
      st[7] = summary.linear_solver_time_in_seconds;
    }
  };
  auto t_solve = std::chrono::steady_clock::now();
  const double cpu0 = cpu_seconds();
  std::vector<std::thread> pool;
  for (int i = 0; i < s.threads; ++i) pool.emplace_back(worker);
  for (auto& th : pool) th.join();
  const double solve_s = seconds_since(t_solve), cpu_s = cpu_seconds() - cpu0;

  auto t_write = std::chrono::steady_clock::now();
  write_raw(dir + "/solution.f64", solution);
  write_raw(dir + "/stats.f64", stats);
  const double write_s = seconds_since(t_write);
  std::printf("{\"ceres\": \"%s\", \"texels\": %lld, \"threads\": %d, \"solve_s\": %.6f, \"cpu_s\": %.6f, "
              "\"read_s\": %.6f, \"write_s\": %.6f}\n",
              CERES_VERSION_STRING, static_cast<long long>(n), s.threads, solve_s, cpu_s, read_s, write_s);
  return 0;
}
