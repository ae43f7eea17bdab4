// Matrix exponential of the augmented ZOH matrix [[A, B, c], [0, 0, 0]]: the C++ twin of
// model/discretization.py expm (same degree table, scaling and squaring).
#pragma once

#include <vector>

#include <Eigen/Core>

namespace pgpc {
using Mat = Eigen::MatrixXd;
using Vec = Eigen::VectorXd;
using Index = Eigen::Index;

// exp(M) of an (n, n) matrix whose rows n_top.. are zero, computed on the n_top top rows only
// (the other rows of exp(M) are those of the identity). Workspaces are kept between calls.
class TopRowsExpm {
 public:
  // degree_norms: discretization._DEGREE_NORMS (largest norm of each Taylor degree K = 1, 2, ...)
  void set_table(std::vector<double> degree_norms);
  // E (n_top, n) = top rows of exp(M) for M_top = the top rows of M; false if M has NaN/inf
  bool run(const Mat &M_top, Mat &E);

 private:
  std::vector<double> norms_, inv_fact_;
  Mat M_, P_, Pn_, E2_;
};
}  // namespace pgpc
