// ltbake: the command-line entry point.
#include "cli/commands.h"

int main(int argc, char** argv) { return ltb::cli::LtbakeMain(argc, argv); }
