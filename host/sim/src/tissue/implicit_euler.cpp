// Implicit (backward) Euler after Baraff & Witkin (1998): one Newton step, solved by Eigen's conjugate gradient.
#include "eyesim/sim/tissue/integrator.hpp"
#include "node_limits.hpp"

#include <Eigen/IterativeLinearSolvers>
#include <Eigen/SparseCore>

#include <algorithm>
#include <cmath>

namespace eyesim::sim::tissue {

namespace {

using SpMat = Eigen::SparseMatrix<double, Eigen::RowMajor, int>;

/// (M − h·∂f/∂v − h²·∂f/∂x) Δv = h·(f + h·∂f/∂x·v), then v += Δv, x += h·v.
/// Spring Jacobian block K_s = k [n nᵀ + max(0, 1 − L/ℓ)(I − n nᵀ)]: the compressive part of the transverse
/// term is dropped (standard), so the matrix is symmetric positive definite and CG applies. Kinematic nodes get
/// identity rows (Δv = 0) and their couplings are moved to the right-hand side through their known velocity.
/// The sparsity pattern and the value slot of every 3×3 block are built once per topology version; a step only
/// rewrites values.
class ImplicitEuler final : public Integrator {
public:
    IntegratorKind kind() const override { return IntegratorKind::kImplicitEuler; }

    void advance(MassSpringSystem& s, const TissueParams& p, float dt_f) override {
        if (version_ != s.topology_version || nodes_ != s.node_count() || springs_ != s.spring_count()) rebuild(s);
        const double h = dt_f;
        const size_t n = s.node_count();
        double* val = A_.valuePtr();
        std::fill(val, val + A_.nonZeros(), 0.0);
        // Diagonal: mass (+ implicit fluid drag); identity rows for kinematic nodes.
        for (size_t i = 0; i < n; ++i) {
            const bool dyn = s.w_per_mg[i] > 0.0f;
            const double m = dyn ? 1.0 / double(s.w_per_mg[i]) : 1.0;
            const double d = dyn ? m * (1.0 + h * double(p.drag_per_s)) : 1.0;
            for (int r = 0; r < 3; ++r) val[diag_[i].row[r] + r] = d;
            const Vec3f f = s.f_nN[i];
            for (int r = 0; r < 3; ++r) b_[3 * i + r] = dyn ? h * double(f[r]) : 0.0;
        }
        // Springs: add h·D_s + h²·K_s to the matrix and h²·K_s (v_b − v_a) to the rhs of a (opposite for b).
        for (size_t k = 0; k < s.springs.size(); ++k) {
            const Spring& sp = s.springs[k];
            const bool da = s.w_per_mg[sp.a] > 0.0f, db = s.w_per_mg[sp.b] > 0.0f;
            if (!da && !db) continue;
            const Eigen::Vector3d dvec = (s.x_mm[sp.b] - s.x_mm[sp.a]).cast<double>();
            const double len = dvec.norm();
            if (!(len > 1e-12)) continue;
            const Eigen::Vector3d nrm = dvec / len;
            const double kk = sp.stiffness_nN_per_mm, cc = sp.damping_nN_s_per_mm;
            const double geo = std::max(0.0, 1.0 - double(sp.rest_mm) / len);
            const Eigen::Matrix3d nnT = nrm * nrm.transpose();
            const Eigen::Matrix3d Ks = kk * (nnT + geo * (Eigen::Matrix3d::Identity() - nnT));
            const Eigen::Matrix3d B = h * cc * nnT + h * h * Ks;
            const Eigen::Vector3d dv_ba = (s.v_mm_per_s[sp.b] - s.v_mm_per_s[sp.a]).cast<double>();
            const Eigen::Vector3d rhs = h * h * (Ks * dv_ba);
            if (da) {
                add_block(val, diag_[sp.a], B, +1.0);
                b_.segment<3>(3 * sp.a) += rhs;
            }
            if (db) {
                add_block(val, diag_[sp.b], B, +1.0);
                b_.segment<3>(3 * sp.b) -= rhs;
            }
            if (da && db) {
                add_block(val, off_ab_[k], B, -1.0);
                add_block(val, off_ba_[k], B, -1.0);
            }
        }
        cg_.setTolerance(p.cg_tolerance);
        cg_.setMaxIterations(p.cg_max_iterations);
        cg_.compute(A_);
        x_ = cg_.solveWithGuess(b_, x_);
        if (!x_.allFinite()) x_.setZero();  // never let a failed solve poison the state
        last_iterations_ = int(cg_.iterations());
        const detail::EndOfStep end(p);
        for (size_t i = 0; i < n; ++i) {
            if (s.w_per_mg[i] == 0.0f) continue;
            Vec3f v = s.v_mm_per_s[i];
            v += x_.segment<3>(3 * i).cast<float>();
            Vec3f x = s.x_mm[i] + dt_f * v;
            end.apply(x, v);
            s.v_mm_per_s[i] = v;
            s.x_mm[i] = x;
        }
    }

private:
    struct Block {
        int row[3];  // value index of the block's first column in each of its three rows
    };

    static void add_block(double* val, const Block& blk, const Eigen::Matrix3d& B, double sign) {
        for (int r = 0; r < 3; ++r)
            for (int c = 0; c < 3; ++c) val[blk.row[r] + c] += sign * B(r, c);
    }

    Block find_block(uint32_t bi, uint32_t bj) const {
        Block blk{};
        const int* outer = A_.outerIndexPtr();
        const int* inner = A_.innerIndexPtr();
        for (int r = 0; r < 3; ++r) {
            const int row = int(3 * bi) + r;
            const int* it = std::lower_bound(inner + outer[row], inner + outer[row + 1], int(3 * bj));
            blk.row[r] = int(it - inner);
        }
        return blk;
    }

    void rebuild(const MassSpringSystem& s) {
        const size_t n = s.node_count();
        std::vector<Eigen::Triplet<double>> trip;
        trip.reserve(9 * (n + 2 * s.spring_count()));
        auto block = [&](uint32_t bi, uint32_t bj) {
            for (int r = 0; r < 3; ++r)
                for (int c = 0; c < 3; ++c) trip.emplace_back(int(3 * bi) + r, int(3 * bj) + c, 0.0);
        };
        for (uint32_t i = 0; i < n; ++i) block(i, i);
        for (const Spring& sp : s.springs) {
            block(sp.a, sp.b);
            block(sp.b, sp.a);
        }
        A_.resize(int(3 * n), int(3 * n));
        A_.setFromTriplets(trip.begin(), trip.end());
        A_.makeCompressed();
        diag_.resize(n);
        for (uint32_t i = 0; i < n; ++i) diag_[i] = find_block(i, i);
        off_ab_.resize(s.spring_count());
        off_ba_.resize(s.spring_count());
        for (size_t k = 0; k < s.spring_count(); ++k) {
            off_ab_[k] = find_block(s.springs[k].a, s.springs[k].b);
            off_ba_[k] = find_block(s.springs[k].b, s.springs[k].a);
        }
        if (size_t(b_.size()) != 3 * n) {
            b_.setZero(Eigen::Index(3 * n));
            x_.setZero(Eigen::Index(3 * n));
        }
        version_ = s.topology_version;
        nodes_ = n;
        springs_ = s.spring_count();
    }

    SpMat A_;
    std::vector<Block> diag_, off_ab_, off_ba_;
    Eigen::VectorXd b_, x_;
    Eigen::ConjugateGradient<SpMat, Eigen::Lower | Eigen::Upper, Eigen::DiagonalPreconditioner<double>> cg_;
    uint64_t version_ = ~uint64_t{0};
    size_t nodes_ = 0, springs_ = 0;
    int last_iterations_ = 0;
};

}  // namespace

std::unique_ptr<Integrator> make_implicit_euler() { return std::make_unique<ImplicitEuler>(); }

}  // namespace eyesim::sim::tissue
