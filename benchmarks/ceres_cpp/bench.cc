// Benchmark-only C++ Ceres program for benchmarks/ (built by build.sh against Debian's
// libceres-dev; not part of fgopt). AutoDiff costs with the residuals of Ceres' own examples
// (pose_graph_2d, pose_graph_3d, bundle_adjuster), whitened with the upper Cholesky factor
// (R^T R = information), first pose held constant, num_threads = 1.
//
//   ceres_bench <pose2d|pose3d|bal> <file> <5it|converge|tight> <repeats> <estimate_out>
//
// Prints one JSON object; writes the final estimate (rows of the benchmarks/problems.py layout).
#include <ceres/ceres.h>
#include <ceres/rotation.h>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <Eigen/Core>
#include <Eigen/Geometry>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <fstream>
#include <iostream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

using Clock = std::chrono::steady_clock;

// Same repair as fgopt's read_g2o(repair_information="clip") and benchmarks/problems.py:
// eigenvalues below 1e-6 * the largest are raised to it (cubicle has non-PD information).
static int g_repaired = 0;
template <int N>
Eigen::Matrix<double, N, N> UpperSqrt(const Eigen::Matrix<double, N, N>& I) {
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, N, N>> es(I);
  Eigen::Matrix<double, N, 1> lam = es.eigenvalues();
  double floor = 1e-6 * std::max(lam.maxCoeff(), 0.0);
  Eigen::Matrix<double, N, N> J = I;
  if (lam.minCoeff() <= floor) {
    ++g_repaired;
    for (int k = 0; k < N; ++k) lam(k) = std::max(lam(k), floor);
    J = es.eigenvectors() * lam.asDiagonal() * es.eigenvectors().transpose();
    J = 0.5 * (J + J.transpose()).eval();
  }
  return J.llt().matrixU();
}
// CPU seconds of this process (user + system): unlike wall time, not inflated when other
// processes compete for the cores.
static double cpu_now() {
  struct timespec ts;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return ts.tv_sec + 1e-9 * ts.tv_nsec;
}

static double secs(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double>(b - a).count();
}

template <typename T>
T NormalizeAngle(const T& a) {
  T two_pi(2.0 * M_PI);
  return a - two_pi * ceres::floor((a + T(M_PI)) / two_pi);
}

struct Pose2Error {
  Pose2Error(const Eigen::Vector3d& z, const Eigen::Matrix3d& S) : z_(z), S_(S) {}
  template <typename T>
  bool operator()(const T* a, const T* b, T* r) const {
    T c = ceres::cos(a[2]), s = ceres::sin(a[2]);
    T dx = b[0] - a[0], dy = b[1] - a[1];
    Eigen::Matrix<T, 3, 1> e;
    e(0) = c * dx + s * dy - T(z_(0));
    e(1) = -s * dx + c * dy - T(z_(1));
    e(2) = NormalizeAngle(b[2] - a[2] - T(z_(2)));
    Eigen::Map<Eigen::Matrix<T, 3, 1>> res(r);
    res = S_.cast<T>() * e;
    return true;
  }
  Eigen::Vector3d z_;
  Eigen::Matrix3d S_;
};

struct Pose3Error {
  Pose3Error(const Eigen::Vector3d& p, const Eigen::Quaterniond& q, const Eigen::Matrix<double, 6, 6>& S)
      : p_(p), q_(q), S_(S) {}
  template <typename T>
  bool operator()(const T* pa_, const T* qa_, const T* pb_, const T* qb_, T* r) const {
    Eigen::Map<const Eigen::Matrix<T, 3, 1>> pa(pa_), pb(pb_);
    Eigen::Map<const Eigen::Quaternion<T>> qa(qa_), qb(qb_);
    Eigen::Quaternion<T> qa_inv = qa.conjugate();
    Eigen::Quaternion<T> q_ab = qa_inv * qb;
    Eigen::Matrix<T, 3, 1> p_ab = qa_inv * (pb - pa);
    Eigen::Quaternion<T> dq = q_.template cast<T>() * q_ab.conjugate();
    Eigen::Map<Eigen::Matrix<T, 6, 1>> res(r);
    res.template head<3>() = p_ab - p_.template cast<T>();
    res.template tail<3>() = T(2.0) * dq.vec();
    res.applyOnTheLeft(S_.template cast<T>());
    return true;
  }
  Eigen::Vector3d p_;
  Eigen::Quaterniond q_;
  Eigen::Matrix<double, 6, 6> S_;
};

struct Snavely {
  Snavely(double u, double v) : u_(u), v_(v) {}
  template <typename T>
  bool operator()(const T* cam, const T* X, T* r) const {
    T P[3];
    ceres::AngleAxisRotatePoint(cam, X, P);
    P[0] += cam[3];
    P[1] += cam[4];
    P[2] += cam[5];
    T px = -P[0] / P[2], py = -P[1] / P[2];
    T r2 = px * px + py * py;
    T d = T(1.0) + r2 * (cam[7] + cam[8] * r2);
    r[0] = cam[6] * d * px - T(u_);
    r[1] = cam[6] * d * py - T(v_);
    return true;
  }
  double u_, v_;
};

struct Data {
  std::string kind;
  std::vector<double> x;      // pose2d: 3/pose; pose3d: positions 3/pose; bal: cameras then points
  std::vector<double> q;      // pose3d quaternions x y z w
  size_t n = 0, ncam = 0, npt = 0;
};

static bool ReadG2o(const std::string& path, bool is3d, Data& d, ceres::Problem& prob) {
  std::ifstream in(path);
  if (!in) return false;
  std::map<long, std::vector<double>> verts;
  struct E { long i, j; std::vector<double> v; };
  std::vector<E> edges;
  std::string line, tag;
  while (std::getline(in, line)) {
    std::istringstream ss(line);
    if (!(ss >> tag)) continue;
    if (tag == "VERTEX_SE2" || tag == "VERTEX_SE3:QUAT") {
      long id; ss >> id;
      std::vector<double> v; double t;
      while (ss >> t) v.push_back(t);
      verts[id] = v;
    } else if (tag == "EDGE_SE2" || tag == "EDGE_SE3:QUAT") {
      E e; ss >> e.i >> e.j; double t;
      while (ss >> t) e.v.push_back(t);
      edges.push_back(e);
    }
  }
  std::map<long, size_t> index;
  size_t k = 0;
  for (auto& kv : verts) index[kv.first] = k++;
  d.n = verts.size();
  if (!is3d) {
    d.x.resize(3 * d.n);
    for (auto& kv : verts) std::copy(kv.second.begin(), kv.second.begin() + 3, &d.x[3 * index[kv.first]]);
    for (auto& e : edges) {
      Eigen::Matrix3d I;
      const double* u = &e.v[3];
      I << u[0], u[1], u[2], u[1], u[3], u[4], u[2], u[4], u[5];
      Eigen::Matrix3d S = UpperSqrt<3>(I);
      auto* c = new ceres::AutoDiffCostFunction<Pose2Error, 3, 3, 3>(
          new Pose2Error(Eigen::Vector3d(e.v[0], e.v[1], e.v[2]), S));
      prob.AddResidualBlock(c, nullptr, &d.x[3 * index[e.i]], &d.x[3 * index[e.j]]);
    }
    prob.SetParameterBlockConstant(&d.x[0]);
  } else {
    d.x.resize(3 * d.n);
    d.q.resize(4 * d.n);
    for (auto& kv : verts) {
      size_t i = index[kv.first];
      const auto& v = kv.second;
      Eigen::Vector4d q(v[3], v[4], v[5], v[6]);
      q.normalize();
      for (int a = 0; a < 3; ++a) d.x[3 * i + a] = v[a];
      for (int a = 0; a < 4; ++a) d.q[4 * i + a] = q[a];
    }
    for (auto& e : edges) {
      Eigen::Matrix<double, 6, 6> I;
      int t = 7;
      for (int r = 0; r < 6; ++r)
        for (int c = r; c < 6; ++c) { I(r, c) = e.v[t]; I(c, r) = e.v[t]; ++t; }
      Eigen::Matrix<double, 6, 6> S = UpperSqrt<6>(I);
      Eigen::Quaterniond q(e.v[6], e.v[3], e.v[4], e.v[5]);
      q.normalize();
      auto* c = new ceres::AutoDiffCostFunction<Pose3Error, 6, 3, 4, 3, 4>(
          new Pose3Error(Eigen::Vector3d(e.v[0], e.v[1], e.v[2]), q, S));
      size_t i = index[e.i], j = index[e.j];
      prob.AddResidualBlock(c, nullptr, &d.x[3 * i], &d.q[4 * i], &d.x[3 * j], &d.q[4 * j]);
    }
    for (size_t i = 0; i < d.n; ++i)
      if (prob.HasParameterBlock(&d.q[4 * i]))
        prob.SetManifold(&d.q[4 * i], new ceres::EigenQuaternionManifold);
    prob.SetParameterBlockConstant(&d.x[0]);
    prob.SetParameterBlockConstant(&d.q[0]);
  }
  return true;
}

static bool ReadBal(const std::string& path, Data& d, ceres::Problem& prob) {
  FILE* f = fopen(path.c_str(), "r");
  if (!f) return false;
  size_t nobs;
  if (fscanf(f, "%zu %zu %zu", &d.ncam, &d.npt, &nobs) != 3) return false;
  std::vector<int> ci(nobs), pi(nobs);
  std::vector<double> uv(2 * nobs);
  for (size_t k = 0; k < nobs; ++k)
    if (fscanf(f, "%d %d %lf %lf", &ci[k], &pi[k], &uv[2 * k], &uv[2 * k + 1]) != 4) return false;
  d.x.resize(9 * d.ncam + 3 * d.npt);
  for (auto& v : d.x)
    if (fscanf(f, "%lf", &v) != 1) return false;
  fclose(f);
  double* cams = d.x.data();
  double* pts = d.x.data() + 9 * d.ncam;
  for (size_t k = 0; k < nobs; ++k) {
    auto* c = new ceres::AutoDiffCostFunction<Snavely, 2, 9, 3>(new Snavely(uv[2 * k], uv[2 * k + 1]));
    prob.AddResidualBlock(c, nullptr, cams + 9 * ci[k], pts + 3 * pi[k]);
  }
  return true;
}

int main(int argc, char** argv) {
  if (argc < 6) {
    std::cerr << "usage: ceres_bench <pose2d|pose3d|bal> <file> <5it|converge> <repeats> <estimate_out>\n";
    return 2;
  }
  std::string kind = argv[1], path = argv[2], mode = argv[3], est = argv[5];
  int repeats = std::max(1, atoi(argv[4]));
  Data d;
  d.kind = kind;
  auto t0 = Clock::now();
  double c0 = cpu_now();
  ceres::Problem prob;
  bool ok = kind == "bal" ? ReadBal(path, d, prob) : ReadG2o(path, kind == "pose3d", d, prob);
  double load_s = secs(t0, Clock::now());
  double load_cpu_s = cpu_now() - c0;
  if (!ok) { std::cerr << "cannot read " << path << "\n"; return 1; }
  const std::vector<double> x0 = d.x, q0 = d.q;

  ceres::Solver::Options o;
  o.num_threads = 1;
  o.logging_type = ceres::SILENT;
  o.minimizer_progress_to_stdout = false;
  o.linear_solver_type = kind == "bal" ? ceres::SPARSE_SCHUR : ceres::SPARSE_NORMAL_CHOLESKY;
  o.max_num_iterations = kind == "bal" ? 50 : 200;
  if (mode == "5it") {
    o.max_num_iterations = 5;
    o.function_tolerance = 0;
    o.gradient_tolerance = 0;
    o.parameter_tolerance = 0;
  }
  if (mode == "tight") {  // run to the bottom: is the converged cost the same minimum?
    o.max_num_iterations = 500;
    o.function_tolerance = 1e-14;
    o.gradient_tolerance = 1e-16;
    o.parameter_tolerance = 1e-14;
  }
  std::vector<double> samples, cpu_samples;
  ceres::Solver::Summary s;
  for (int k = 0; k <= repeats; ++k) {  // k == 0: warm-up
    d.x = x0;
    d.q = q0;
    auto a = Clock::now();
    double ca = cpu_now();
    ceres::Solve(o, &prob, &s);
    double t = secs(a, Clock::now());
    if (k > 0) cpu_samples.push_back(cpu_now() - ca);
    if (k > 0) samples.push_back(t);
  }
  std::vector<double> sorted = samples;
  std::sort(sorted.begin(), sorted.end());
  size_t m = sorted.size();
  double med = m % 2 ? sorted[m / 2] : 0.5 * (sorted[m / 2 - 1] + sorted[m / 2]);

  std::ofstream out(est);
  out.precision(17);
  if (kind == "pose2d") {
    for (size_t i = 0; i < d.n; ++i) out << d.x[3 * i] << " " << d.x[3 * i + 1] << " " << d.x[3 * i + 2] << "\n";
  } else if (kind == "pose3d") {
    for (size_t i = 0; i < d.n; ++i) {
      out << d.x[3 * i] << " " << d.x[3 * i + 1] << " " << d.x[3 * i + 2];
      for (int a = 0; a < 4; ++a) out << " " << d.q[4 * i + a];
      out << "\n";
    }
  } else {
    for (size_t i = 0; i < d.ncam; ++i) {
      for (int a = 0; a < 9; ++a) out << (a ? " " : "") << d.x[9 * i + a];
      out << "\n";
    }
    for (size_t j = 0; j < d.npt; ++j) {
      const double* p = &d.x[9 * d.ncam + 3 * j];
      out << p[0] << " " << p[1] << " " << p[2] << "\n";
    }
  }
  std::sort(cpu_samples.begin(), cpu_samples.end());
  double cpu_med = m % 2 ? cpu_samples[m / 2] : 0.5 * (cpu_samples[m / 2 - 1] + cpu_samples[m / 2]);
  printf("{\"load_s\": %.9g, \"load_cpu_s\": %.9g, \"solve_s\": %.9g, \"solve_cpu_s\": %.9g, "
         "\"solve_cpu_min_s\": %.9g, \"samples\": [", load_s, load_cpu_s, med, cpu_med,
         cpu_samples[0]);
  for (size_t k = 0; k < samples.size(); ++k) printf("%s%.9g", k ? ", " : "", samples[k]);
  printf("], \"iterations\": %d, \"initial_cost\": %.17g, \"final_cost\": %.17g, "
         "\"termination\": \"%s\", \"linear_solver_s\": %.9g, \"preprocessor_s\": %.9g, "
         "\"minimizer_s\": %.9g, \"ceres\": \"%s\", \"repaired_information\": %d}\n",
         s.num_successful_steps + s.num_unsuccessful_steps - 1, s.initial_cost, s.final_cost,
         ceres::TerminationTypeToString(s.termination_type), s.linear_solver_time_in_seconds,
         s.preprocessor_time_in_seconds, s.minimizer_time_in_seconds, CERES_VERSION_STRING,
         g_repaired);
  return 0;
}
