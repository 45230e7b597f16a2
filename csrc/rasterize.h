// 2DGS CPU rasterizer: projection, tile binning, per-tile depth sort, front-to-back blending with
// early termination, and the analytic backward pass (optionally the FisherRF squared mode).
//
// The equations are those of flightrecon/render/projection.py (the readable statement, tested
// against gsplat) and of docs/equations.md; docs/architecture.md (section "Rasterizer") walks
// through the stages. Once per call, the splats are grouped spatially for culling (SplatGroups).
// Per camera: project the splats of the groups that may reach the frustum (parallel over groups),
// sort the binned ones by depth (ties keep the lower index), list them per 16x16 tile in that
// order, then blend each tile (parallel over tiles), or a whole camera per thread when there are
// many cameras. The blend loops run splats outside and the tile's pixels inside, branch-free, so
// the compiler vectorizes them over pixels; only the pixel groups that a splat's box covers are
// visited (span_of). A single camera's forward can keep its projection and bins for the backward
// (RenderCache), which otherwise recomputes them.
//
// Determinism: every float sum has a fixed order independent of the thread count. The backward
// writes each (tile, splat) pair's gradient into its own slot and reduces the slots per splat in
// tile order; cameras are reduced in camera order.
//
// One file per stage and direction, around this header (the data the stages pass, and the stages'
// declarations):
//   rasterize_project.cpp       splat grouping for culling, frustum tests, projection of a camera
//   rasterize_bin.cpp           Morton order, the depth sort and the tiles' lists
//   rasterize_blend.h           the per-pixel arithmetic both blends share, generic and AVX2
//   rasterize_forward.cpp       forward blend of a tile (AVX2 and generic splat loops), forward
//   rasterize_backward.cpp      backward blend of a tile (AVX2 and generic splat loops), slot
//                               reduction, chain rule to the splats' parameters, backward
//   rasterize_fisher.cpp        the FisherRF squared mode's slots and outputs
//   rasterize_feature_sums.cpp  per-camera sums of a two-sided splat feature (view scoring)
//   rasterize_probe.cpp         the forward blend's ceiling on this CPU (bench map, bench render)
//   rasterize.cpp               camera input, candidate rows and the Python bindings
//   rasterize_torch.h           the torch-facing functions the stage files define
#pragma once

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <memory>
#include <type_traits>
#include <vector>

namespace raster {

// ---------------------------------------------------------------- constants

constexpr int TS = 16;          // tile side
constexpr int LANES = 8;        // pixel group: one AVX2 float vector; a splat's groups start at its box's first column
constexpr int RS = TS + LANES;  // row stride of a tile's pixel arrays: a group from any column stays in its row
constexpr int TP = (TS + 1) * RS;  // pixel slots per tile: padding columns and a padding row, never blended
constexpr double ALPHA_MIN = 1.0 / 255.0;
constexpr double ALPHA_MAX = 0.99;
constexpr double T_MIN = 1e-4;
constexpr double CUTOFF = 3.33;
constexpr double FILTER_INV_SQ = 2.0;
constexpr double FILTER_REACH = 2.36;
constexpr double BOX_EPS = 1e-3;
constexpr double RHO_MARGIN = 1e-3;  // alpha margin exp(-5e-4): covers float error of rho and exp
constexpr int NG = 11;           // per-pixel geometric gradient: T_u, T_v, T_w (9), means2d (2)
constexpr int NSYM = NG * (NG + 1) / 2;
constexpr int REC = 15;  // a Bins record: ray transform (9), means2d (2), opacity, normal (3); features follow
constexpr int GROUP = 32;  // splats per culling group (SplatGroups)
constexpr int BLOCK = 32;  // culling groups per block (SplatGroups): a camera tests a group only in a block it may see

// ---------------------------------------------------------------- inputs and settings

struct Camera {
  double R[9], t[3], K[9];
};

struct Settings {
  int W, H, tiles_x, tiles_y;
  double near, far;
};

inline Settings settings_of(int64_t W, int64_t H, double near, double far) {
  return Settings{int(W), int(H), int((W + TS - 1) / TS), int((H + TS - 1) / TS), near, far};
}

struct Flags {
  bool normal, depth, dist;
  bool track;  // median depth and the last/median splat per pixel (the backward needs them)
};

// Phase timings (seconds) and blend work of the last forward or backward call, for profiling.
struct Stats {
  double project = 0, bin = 0, sort = 0, blend = 0, reduce = 0, chain = 0;
  int64_t evals = 0, blends = 0, isects = 0;  // pixel-splat evaluations, those that blend, tile-splat pairs
  int64_t tests = 0, projected = 0, binned = 0;  // culling spheres tested, splats projected, splats binned
  bool by_camera = false;  // timings are then summed over threads (thread-seconds), not wall time
  void add(const Stats& o) {
    project += o.project; bin += o.bin; sort += o.sort; blend += o.blend; reduce += o.reduce;
    chain += o.chain; evals += o.evals; blends += o.blends; isects += o.isects;
    tests += o.tests; projected += o.projected; binned += o.binned;
  }
};
extern Stats g_stats;  // rasterize.cpp; last_stats reads it

// ---------------------------------------------------------------- what the stages pass

// Splats regrouped for frustum culling, once per call (nothing here depends on the camera): sorted
// along a Morton curve of their means, so each run of GROUP consecutive positions is spatially
// compact, and each run (group) gets a sphere holding its splats' bounding spheres. A camera then
// projects only the splats of the groups whose sphere may reach its frustum, instead of all N.
// Runs of BLOCK consecutive groups (blocks) get a sphere holding their groups' spheres, so a
// camera tests the groups of the blocks it may see, not every group of the map.
// Without culling (one camera) the splats stay in id order and nothing is copied.
// The per-splat values that do not depend on the camera live here too, in the same order: the
// bounding-sphere radius of the frustum test and the opacity-aware cutoff (rho_max, <= 0 when the
// splat can never reach ALPHA_MIN) with its conic scale and filter reach.
template <typename S>
struct SplatGroups {
  int64_t N = 0;
  std::vector<int32_t> id;                   // position -> splat id
  const S *mean, *U, *V, *n, *opac;          // by position (3 values a splat, opac 1)
  std::vector<S> sorted;                     // what they point to when culling, else the inputs
  std::vector<S> rad, cut, freach;
  std::vector<double> rho_max;
  std::vector<double> sphere;                // per group when culling: center (3), radius
  std::vector<double> block;                 // per block when culling: center (3), radius
  SplatGroups() = default;
  SplatGroups(const SplatGroups&) = delete;  // the pointers may point into `sorted`
  SplatGroups(SplatGroups&&) = default;
  bool culls() const { return !sphere.empty(); }
  int groups() const { return int((N + GROUP - 1) / GROUP); }
  int64_t begin(int g) const { return int64_t(g) * GROUP; }
  int64_t end(int g) const { return std::min(N, int64_t(g + 1) * GROUP); }
  int blocks() const { return (groups() + BLOCK - 1) / BLOCK; }
};

// One camera's projected splats (struct of arrays over all N splats, by SplatGroups position).
// Only the splats of the groups that pass the camera's frustum test are written (project_camera);
// the backward, which reads every splat's rect, does not cull.
template <typename S>
struct Projected {
  std::vector<S> M, m2d, depth, nrm, sign;
  std::vector<int> rect;  // px0, py0, px1, py1 (inclusive); px0 > px1 when not binned
  std::vector<int> radii;
  explicit Projected(int64_t n)
      : M(9 * n), m2d(2 * n), depth(n), nrm(3 * n), sign(n), rect(4 * n), radii(n) {}
};

// What one camera may see: the groups that pass the frustum test (their splats are projected, the
// others keep radius 0) and, of their splats, the positions that touch the image, increasing.
struct Visible {
  int64_t tests = 0, projected = 0;  // spheres tested (blocks and groups), splats projected (Stats)
  std::vector<int32_t> groups;
  std::vector<uint32_t> masks;  // per passing group: a bit for each binned splat
  std::vector<int32_t> binned;
};
static_assert(GROUP <= 32, "a group's binned splats are one 32-bit mask");

// One camera's binned splats. The splats that touch the image are packed into contiguous records
// (the blend reads one record per splat instead of chasing ids through N-sized arrays), sorted
// once by depth, and each tile lists its records in that order, so no per-tile sort is needed.
template <typename S>
struct Bins {
  std::vector<int64_t> offsets;  // [tiles + 1]
  std::vector<int32_t> ids;      // per tile: record indices in depth order
  std::vector<int32_t> splat;    // record -> splat id
  std::vector<int32_t> rect;     // record -> px0, py0, px1, py1 (inclusive)
  std::vector<S> rec;            // records, REC + D values each
  int R = REC;
  // feature_sums' cut (empty: none), per list entry: a pixel whose transmittance is below stop_T
  // stops before the entry, and left_max is the largest feature from the entry to the end of its
  // tile's list, so what the pixel leaves out is at most its transmittance times left_max.
  std::vector<S> stop_T, left_max;
  // Per list entry (a splat in a tile), when the AVX2 forward kept it for the backward: a bit for each
  // pixel group it visited in which some pixel blended (group_bit), so the backward evaluates only
  // those. Empty: not recorded, the backward evaluates every group.
  std::vector<uint32_t> blended;
};

// Where forward_tile writes one camera's images (null: not rendered), and Bins::blended (null: not
// recorded).
template <typename S>
struct FwdOut {
  S *feat, *alpha, *normal, *zsum, *msum, *m2sum, *median;
  int32_t *last, *medj;
  uint32_t* blended = nullptr;
};

struct TileWork {
  int64_t evals = 0, blends = 0;
  double left = 0;  // with Bins::stop_T: the sum over the pixels it stopped of transmittance x left_max
};

// One camera's projection and bins as a forward call computed them, kept for its backward (which
// would otherwise redo the same projection, binning and sort). Only a single camera's are kept:
// its splats stay in id order, the order the backward works in; a batch's forward orders them
// spatially. Python holds it as an opaque handle; the backward checks that it fits its inputs.
template <typename S>
struct KeptCamera {
  Projected<S> P;
  Bins<S> B;
  int64_t N, D, W, H;
  double near, far;
  Camera cam;
  bool fits(int64_t n, int64_t d, int64_t w, int64_t h, double nr, double fr, const Camera& c) const {
    return n == N && d == D && w == W && h == H && nr == near && fr == far &&
           std::memcmp(&c, &cam, sizeof(Camera)) == 0;
  }
};

struct RenderCache {
  std::unique_ptr<KeptCamera<float>> f;
  std::unique_ptr<KeptCamera<double>> d;
  template <typename S>
  std::unique_ptr<KeptCamera<S>>& get() {
    if constexpr (std::is_same<S, float>::value) return f;
    else return d;
  }
};

// ---------------------------------------------------------------- the stages (S: float or double)

// rasterize_project.cpp
// spatial: groups in Morton order, for culling; else in id order (position == id), no culling.
template <typename S>
SplatGroups<S> group_splats(const S* means, const S* U, const S* V, const S* n, const S* opac, int64_t N,
                            bool spatial);
template <typename S>
void project_camera(const SplatGroups<S>& G, const Camera& cam, const Settings& st, Projected<S>& P,
                    Visible& vis);
// One camera's radii by splat id (0 where not visible).
template <typename S>
void write_radii(const SplatGroups<S>& G, const Visible& vis, const Projected<S>& P, int32_t* radii);
// Per splat (by id), 1 if it passes project_splat's first test for one camera (with a float
// slack): every splat the camera can draw is among them.
template <typename S>
std::vector<uint8_t> candidate_mask(const S* means, const S* U, const S* V, int64_t N, const Camera& cam,
                                    const Settings& st);

// rasterize_bin.cpp
// Splat ids in Morton order of their means quantized in the means' bounding box.
template <typename S>
std::vector<int32_t> morton_order(const S* means, int64_t N);
// The records of one camera's binned splats (features feat [N, D] by splat id), sorted by depth
// and listed per tile. With `keep_tile` ([tiles], row-major), a tile whose flag is 0 lists no
// splat: the blend leaves its pixels empty and the backward has nothing to do there.
template <typename S>
Bins<S> bin_and_sort(const Projected<S>& P, const SplatGroups<S>& G, const Visible& vis, const S* feat, int D,
                     const Settings& st, Stats& stats, const uint8_t* keep_tile = nullptr);

// rasterize_forward.cpp
// Blends tile `tile` front to back into `out`; TRACK: also the median depth and last/median splats.
template <typename S, bool TRACK>
TileWork forward_tile(int tile, const Bins<S>& B, int D, const Settings& st, const Flags& fl,
                      const FwdOut<S>& out);

// rasterize_fisher.cpp
// A (tile, splat) slot of the Fisher mode from the splat's per-pixel geometric gradients gg[NG][TP]
// over slots [p0, p1) and its sums of dL/do^2 and w^2.
template <typename S>
void fisher_slot(const S (*gg)[TP], int p0, int p1, S o2, S w2, S* slot);
// One camera's reduced Fisher rows (rows [records, G]) into its outputs by splat id: fg [N, NSYM],
// fo [N], fw [N].
template <typename S>
void fisher_rows(const Bins<S>& B, int G, const std::vector<S>& rows, S* fg, S* fo, S* fw);

// rasterize_probe.cpp
// Pixel-splat evaluations per second per thread of the forward blend where no group is partial and
// the records stay in cache: when every evaluation blends, and when every one is rejected by the
// alpha gate; measured for `seconds` in all on all threads at once.
struct CeilingProbe {
  double blend_per_s_thread = 0, reject_per_s_thread = 0;
  int threads = 1;
};
CeilingProbe blend_ceiling(double seconds);

}  // namespace raster
