// SPDX-License-Identifier: BSD-3-Clause
#include "iwlomap/slam/pose_graph.h"

#include <ceres/ceres.h>
#include <ceres/manifold.h>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>

#include <cmath>
#include <stdexcept>
#include <string>

namespace iwlomap::slam {

namespace {

// Residual of one constraint: the measured pose of b in a's frame against the estimate, whitened.
struct RelativePoseError {
  Eigen::Vector3d t_measured;
  Eigen::Quaterniond q_measured;
  Matrix6d sqrt_information;

  template <class T>
  bool operator()(const T* ta_, const T* qa_, const T* tb_, const T* qb_, T* out) const {
    const Eigen::Map<const Eigen::Matrix<T, 3, 1>> ta(ta_), tb(tb_);
    const Eigen::Map<const Eigen::Quaternion<T>> qa(qa_), qb(qb_);
    const Eigen::Quaternion<T> qa_inv = qa.conjugate();
    const Eigen::Matrix<T, 3, 1> t_ab = qa_inv * (tb - ta);
    const Eigen::Quaternion<T> q_error = q_measured.template cast<T>().conjugate() * (qa_inv * qb);
    Eigen::Matrix<T, 6, 1> r;
    r.template head<3>() = t_ab - t_measured.template cast<T>();
    r.template tail<3>() = T(2.0) * q_error.vec();
    Eigen::Map<Eigen::Matrix<T, 6, 1>> residual(out);
    residual = sqrt_information.template cast<T>() * r;
    return true;
  }
};

class StopCallback : public ceres::IterationCallback {
 public:
  explicit StopCallback(const StopToken& stop) : stop_(stop) {}
  ceres::CallbackReturnType operator()(const ceres::IterationSummary&) override {
    return stop_.stop_requested() ? ceres::SOLVER_ABORT : ceres::SOLVER_CONTINUE;
  }

 private:
  const StopToken& stop_;
};

Matrix6d sqrt_of(const Matrix6d& information) {
  // Upper-triangular S with S^T S = information; the eigen decomposition copes with a matrix that
  // is only semi-definite (a direction with no information).
  const Eigen::SelfAdjointEigenSolver<Matrix6d> eig(information);
  const Vector6d root = eig.eigenvalues().cwiseMax(0.0).cwiseSqrt();
  return root.asDiagonal() * eig.eigenvectors().transpose();
}

double whitened(const PoseConstraint& c, const std::vector<Eigen::Isometry3d>& nodes) {
  const Eigen::Isometry3d estimate = nodes[c.from].inverse() * nodes[c.to];
  Vector6d r;
  r.head<3>() = estimate.translation() - c.measurement.translation();
  const Eigen::Quaterniond q_error =
      Eigen::Quaterniond(c.measurement.linear()).conjugate() * Eigen::Quaterniond(estimate.linear());
  r.tail<3>() = (q_error.w() < 0 ? -2.0 : 2.0) * q_error.vec();
  return std::sqrt(std::max(0.0, r.dot(c.information * r)));
}

}  // namespace

void PoseGraph::validate() const {
  for (std::size_t i = 0; i < nodes.size(); ++i)
    if (!nodes[i].matrix().allFinite())
      throw std::invalid_argument("iwlomap: PoseGraph: node " + std::to_string(i) + " is not finite");
  for (std::size_t k = 0; k < constraints.size(); ++k) {
    const PoseConstraint& c = constraints[k];
    const std::string name = "iwlomap: PoseGraph: constraint " + std::to_string(k);
    if (c.from >= nodes.size() || c.to >= nodes.size())
      throw std::invalid_argument(name + " joins nodes " + std::to_string(c.from) + " and " + std::to_string(c.to) +
                                  " of " + std::to_string(nodes.size()));
    if (c.from == c.to) throw std::invalid_argument(name + " joins node " + std::to_string(c.from) + " to itself");
    if (!c.measurement.matrix().allFinite() || !c.information.allFinite())
      throw std::invalid_argument(name + " is not finite");
    if (!c.information.isApprox(c.information.transpose(), 1e-9) ||
        Eigen::SelfAdjointEigenSolver<Matrix6d>(c.information).eigenvalues().minCoeff() <
            -1e-9 * c.information.cwiseAbs().maxCoeff())
      throw std::invalid_argument(name + ": the information matrix is not symmetric positive semi-definite");
  }
}

void PoseGraphOptions::validate() const {
  if (max_iterations < 1) throw std::invalid_argument("iwlomap: PoseGraphOptions: max_iterations must be >= 1");
  if (!(robust_scale > 0.0) || !std::isfinite(robust_scale))
    throw std::invalid_argument("iwlomap: PoseGraphOptions: robust_scale = " + std::to_string(robust_scale) +
                                " must be finite and > 0");
  if (!(outlier_sigmas > 0.0)) throw std::invalid_argument("iwlomap: PoseGraphOptions: outlier_sigmas must be > 0");
  if (max_rejection_rounds < 0)
    throw std::invalid_argument("iwlomap: PoseGraphOptions: max_rejection_rounds must be >= 0");
}

Matrix6d information_from_sigmas(double translation_sigma, double rotation_sigma) {
  if (!(translation_sigma > 0.0 && rotation_sigma > 0.0))
    throw std::invalid_argument("iwlomap: information_from_sigmas: the sigmas must be > 0");
  Vector6d d;
  d << Eigen::Vector3d::Constant(1.0 / (translation_sigma * translation_sigma)),
      Eigen::Vector3d::Constant(1.0 / (rotation_sigma * rotation_sigma));
  return d.asDiagonal();
}

PoseGraphSolution solve_pose_graph(const PoseGraph& graph, const PoseGraphOptions& options, const StopToken& stop) {
  graph.validate();
  options.validate();
  PoseGraphSolution out;
  out.nodes = graph.nodes;
  out.rejected.assign(graph.constraints.size(), false);
  out.whitened_error.assign(graph.constraints.size(), 0.0);
  if (graph.nodes.empty()) return out;

  for (int round = 0; round <= options.max_rejection_rounds; ++round) {
    // Every solve starts from the graph's initial values, so the result depends on the graph and
    // the set of rejected constraints only.
    std::vector<Eigen::Vector3d> t(graph.nodes.size());
    std::vector<Eigen::Quaterniond> q(graph.nodes.size());
    for (std::size_t i = 0; i < graph.nodes.size(); ++i) {
      t[i] = graph.nodes[i].translation();
      q[i] = Eigen::Quaterniond(graph.nodes[i].linear()).normalized();
    }
    ceres::Problem::Options problem_options;
    problem_options.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
    problem_options.loss_function_ownership = ceres::TAKE_OWNERSHIP;
    ceres::Problem problem(problem_options);
    ceres::EigenQuaternionManifold quaternion_manifold;
    for (std::size_t k = 0; k < graph.constraints.size(); ++k) {
      if (out.rejected[k]) continue;
      const PoseConstraint& c = graph.constraints[k];
      auto* cost = new ceres::AutoDiffCostFunction<RelativePoseError, 6, 3, 4, 3, 4>(new RelativePoseError{
          c.measurement.translation(), Eigen::Quaterniond(c.measurement.linear()).normalized(), sqrt_of(c.information)});
      ceres::LossFunction* loss = c.robust ? new ceres::HuberLoss(options.robust_scale) : nullptr;
      problem.AddResidualBlock(cost, loss, t[c.from].data(), q[c.from].coeffs().data(), t[c.to].data(),
                               q[c.to].coeffs().data());
    }
    for (std::size_t i = 0; i < graph.nodes.size(); ++i) {
      if (!problem.HasParameterBlock(t[i].data())) continue;  // a node no constraint reaches keeps its value
      problem.SetManifold(q[i].coeffs().data(), &quaternion_manifold);
    }
    if (problem.HasParameterBlock(t[0].data())) {
      problem.SetParameterBlockConstant(t[0].data());
      problem.SetParameterBlockConstant(q[0].coeffs().data());
    }
    ceres::Solver::Options solver;
    solver.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
    solver.max_num_iterations = options.max_iterations;
    solver.num_threads = 1;
    solver.logging_type = ceres::SILENT;
    StopCallback callback(stop);
    solver.callbacks.push_back(&callback);
    ceres::Solver::Summary summary;
    ceres::Solve(solver, &problem, &summary);
    if (stop.stop_requested()) throw StopRequested();
    if (round == 0) out.initial_cost = summary.initial_cost;
    out.final_cost = summary.final_cost;
    out.iterations += static_cast<int>(summary.iterations.size());
    ++out.solves;
    for (std::size_t i = 0; i < graph.nodes.size(); ++i) {
      out.nodes[i].setIdentity();
      out.nodes[i].linear() = q[i].normalized().toRotationMatrix();
      out.nodes[i].translation() = t[i];
    }
    // The worst robust constraint beyond outlier_sigmas goes, one per solve: a false closure pulls
    // the true ones off too, so those above the threshold in the same solve are not all outliers.
    std::size_t worst = graph.constraints.size();
    for (std::size_t k = 0; k < graph.constraints.size(); ++k) {
      out.whitened_error[k] = whitened(graph.constraints[k], out.nodes);
      if (graph.constraints[k].robust && !out.rejected[k] && out.whitened_error[k] > options.outlier_sigmas &&
          (worst == graph.constraints.size() || out.whitened_error[k] > out.whitened_error[worst]))
        worst = k;
    }
    if (worst == graph.constraints.size() || round == options.max_rejection_rounds) break;
    out.rejected[worst] = true;
  }
  return out;
}

}  // namespace iwlomap::slam
