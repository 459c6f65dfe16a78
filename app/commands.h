// One function per `sope <command>`: binds flags to options (CLI11), checks them, calls
// library code. argv[0] is the command name. Returns the process exit code; throws
// sope::Error for failures, which main() prints as one line.
#pragma once

namespace sope {

int RunPatterns(int argc, char** argv);
int RunSimulate(int argc, char** argv);
int RunDecode(int argc, char** argv);
int RunScan(int argc, char** argv);
int RunProject(int argc, char** argv);
int RunCalibrate(int argc, char** argv);
int RunCalibrateGamma(int argc, char** argv);
int RunBuildDb(int argc, char** argv);
int RunRecognise(int argc, char** argv);
int RunScanAndRecognise(int argc, char** argv);
int RunEval(int argc, char** argv);
int RunObjects(int argc, char** argv);

}  // namespace sope
