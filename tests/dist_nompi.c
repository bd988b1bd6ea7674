// include/matlaber/dist.h as a build without MPI has it (src/core/dist.c compiled once more without
// MLB_HAVE_MPI, CMakeLists.txt): one process whose collectives copy, and a clear refusal when a
// launcher started several copies (mpirun / srun on a build without MPI).
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/dist.h"
#include "test.h"

TEST(refuses_several_copies) {
    setenv("OMPI_COMM_WORLD_SIZE", "2", 1);
    int argc = 1;
    char* args[] = {"x", NULL};
    char** argv = args;
    CHECK(mlb_dist_init(&argc, &argv) == MLB_ERR_UNSUPPORTED);
    CHECK(strstr(mlb_last_error(), "built without MPI") != NULL);
    CHECK(strstr(mlb_last_error(), "OMPI_COMM_WORLD_SIZE=2") != NULL);
    unsetenv("OMPI_COMM_WORLD_SIZE");
    CHECK(!mlb_dist_built() && !strcmp(mlb_dist_transport(), "none"));
    CHECK(mlb_dist_rank() == 0 && mlb_dist_size() == 1);
}

TEST(shares_and_copies) {
    // 4 views over 3 ranks: 1, 1, 2, contiguous, in rank order; more ranks than views: empty shares
    int want[3][2] = {{0, 1}, {1, 1}, {2, 2}};
    for (int r = 0; r < 3; r++) {
        int f, c;
        mlb_dist_share_of(4, r, 3, &f, &c);
        CHECK(f == want[r][0] && c == want[r][1]);
    }
    int f, c;
    mlb_dist_share_of(1, 0, 2, &f, &c);
    CHECK(c == 0);
    mlb_dist_share_of(1, 1, 2, &f, &c);
    CHECK(f == 0 && c == 1);
    mlb_dist_share(9, &f, &c);
    CHECK(f == 0 && c == 9);
    // micro-batches handed out whole: 4 views in batches of 3 over 2 ranks: [0, 3) and [3, 4);
    // batches of 2 over 3 ranks: none, [0, 2), [2, 4); batch 0 (one batch) over 2: none, [0, 4);
    // 5 views in batches of 2 over 2 ranks: [0, 2), [2, 5); batches of 1 are mlb_dist_share_of's shares
    int want_b[][6] = {{4, 3, 2, 0, 0, 3}, {4, 3, 2, 1, 3, 1}, {4, 2, 3, 0, 0, 0}, {4, 2, 3, 1, 0, 2},
                       {4, 2, 3, 2, 2, 2}, {4, 0, 2, 0, 0, 0}, {4, 0, 2, 1, 0, 4}, {4, 9, 2, 1, 0, 4},
                       {5, 2, 2, 0, 0, 2}, {5, 2, 2, 1, 2, 3}};   // n, batch, size, rank -> first, count
    for (size_t i = 0; i < sizeof want_b / sizeof want_b[0]; i++) {
        const int* w = want_b[i];
        mlb_dist_share_batches_of(w[0], w[1], w[3], w[2], &f, &c);
        CHECK_MSG(f == w[4] && c == w[5], "n %d batch %d rank %d of %d: [%d, +%d)", w[0], w[1], w[3], w[2], f, c);
    }
    for (int r = 0; r < 3; r++) {
        int f1, c1;
        mlb_dist_share_of(7, r, 3, &f, &c);
        mlb_dist_share_batches_of(7, 1, r, 3, &f1, &c1);
        CHECK(f == f1 && c == c1);
    }
    mlb_dist_share_batches(9, 4, &f, &c);   // one process: every batch
    CHECK(f == 0 && c == 9);
    float mine[3] = {1, 2, 3}, all[3] = {0};
    CHECK(mlb_dist_allgather_items(mine, all, 3, sizeof(float)) == MLB_OK);
    CHECK(!memcmp(mine, all, sizeof mine));
    float all2[3] = {0};
    CHECK(mlb_dist_allgather_batches(mine, all2, 3, 2, sizeof(float)) == MLB_OK);
    CHECK(!memcmp(mine, all2, sizeof mine));
    CHECK(mlb_dist_max_int(5) == 5);
    CHECK(mlb_dist_bcast(all, sizeof all, 0) == MLB_OK && mlb_dist_barrier() == MLB_OK);
    // the batches' vectors added left to right, out = v_0 for one batch, out may be the first vector
    float v[3][3] = {{1e8f, 1, -0.0f}, {-1e8f, 2, -0.0f}, {1, 3, -0.0f}}, sum[3];
    CHECK(mlb_dist_sum_batches(v[0], sum, 3, 3) == MLB_OK);
    CHECK(sum[0] == (1e8f + -1e8f) + 1 && sum[1] == 6 && sum[2] == 0 && signbit(sum[2]));
    CHECK(mlb_dist_sum_batches(v[1], sum, 3, 1) == MLB_OK && !memcmp(sum, v[1], sizeof sum));
    CHECK(mlb_dist_sum_batches(v[0], v[0], 3, 2) == MLB_OK && v[0][0] == 0 && v[0][1] == 3);
    int outer = mlb_dist_solo(1);   // sections nest: each gives back the state it found
    CHECK(outer == 0 && mlb_dist_size() == 1);
    int inner = mlb_dist_solo(1);
    CHECK(inner == 1);
    mlb_dist_solo(inner);   // the inner section's end leaves the outer one solo
    CHECK(mlb_dist_size() == 1 && mlb_dist_rank() == 0);
    CHECK(mlb_dist_solo(outer) == 1);
}

int main(void) {
    RUN(refuses_several_copies);
    RUN(shares_and_copies);
    return test_summary();
}
