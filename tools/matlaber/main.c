// matlaber: the command-line program. One file per command group (cmd_*.c).
#include <stdio.h>
#include <string.h>
#include "matlaber/log.h"
int main(int argc, char** argv) {
    mlb_log_set_sink(mlb_log_file_sink, stderr);
    printf("matlaber\n");
    return 0;
}
