// include/matlaber/dist.h as a build without MPI has it (src/core/dist.c compiled once more without
// MLB_HAVE_MPI, CMakeLists.txt): one process whose collectives copy, and a clear refusal when a
// launcher started several copies (mpirun / srun on a build without MPI).
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
    float mine[3] = {1, 2, 3}, all[3] = {0};
    CHECK(mlb_dist_allgather_items(mine, all, 3, sizeof(float)) == MLB_OK);
    CHECK(!memcmp(mine, all, sizeof mine));
    CHECK(mlb_dist_max_int(5) == 5);
    CHECK(mlb_dist_bcast(all, sizeof all, 0) == MLB_OK && mlb_dist_barrier() == MLB_OK);
    mlb_dist_solo(1);
    CHECK(mlb_dist_size() == 1);
    mlb_dist_solo(0);
}

int main(void) {
    RUN(refuses_several_copies);
    RUN(shares_and_copies);
    return test_summary();
}
