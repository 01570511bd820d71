// Probe of OpenNI2 2.2 teardown on the Dummy device: which stop/destroy/close/oniShutdown
// orders segfault. Build and run (exit code 139 = segfault):
//   g++ -O1 -I/usr/include/openni2 shutdown_probe.cpp -lOpenNI2 -o probe
//   for m in 0 1 2 3 4 5 6 7 8 9 10 11; do for r in $(seq 10); do ./probe $m >/dev/null 2>&1; echo -n "$? "; done; echo "<- mode $m"; done
// Measured here (machine loaded): mode 2 (oniShutdown with streams running) crashes every run
// (10/10); modes 6, 9, 10 (no pause between stop and destroy) crash 14/20, 10/20 and 13/20;
// modes 0, 1, 3, 4, 5, 7, 8 0/10 and 11 (stop, pause, destroy, close, pause, shutdown) 0/20.
// Hence: pause 100 ms between stopping and destroying, and never call oniShutdown (nothing
// is gained at process exit, and a driver thread still running makes it crash).
#include <OniCAPI.h>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <unistd.h>
int main(int argc, char** argv) {
  int mode = atoi(argv[1]);
  if (oniInitialize(2002) != ONI_STATUS_OK) { printf("init fail %s\n", oniGetExtendedError()); return 1; }
  OniDeviceHandle dev; if (oniDeviceOpen("Dummy", &dev)) { printf("open fail\n"); return 1; }
  OniStreamHandle d, c; oniDeviceCreateStream(dev, ONI_SENSOR_DEPTH, &d); oniDeviceCreateStream(dev, ONI_SENSOR_COLOR, &c);
  oniStreamStart(d); oniStreamStart(c);
  for (int i = 0; i < 20; i++) { int idx; OniStreamHandle s[2] = {d, c}; oniWaitForAnyStream(s, 2, &idx, 1000); OniFrame* f; oniStreamReadFrame(s[idx], &f); oniFrameRelease(f); }
  switch (mode) {
  case 0: oniStreamStop(d); oniStreamStop(c); usleep(100000); oniStreamDestroy(d); oniStreamDestroy(c); oniDeviceClose(dev); oniShutdown(); break; // proper + shutdown
  case 1: oniStreamStop(d); oniStreamStop(c); usleep(100000); oniStreamDestroy(d); oniStreamDestroy(c); oniDeviceClose(dev); break; // proper, no shutdown
  case 2: oniShutdown(); break; // shutdown with running streams
  case 3: break; // exit with running streams, no shutdown
  case 4: oniStreamStop(d); oniStreamStop(c); usleep(100000); break; // stopped, not destroyed, exit
  case 5: oniStreamStop(d); oniStreamStop(c); usleep(100000); oniShutdown(); break; // stopped, shutdown
  case 6: oniStreamStop(d); oniStreamStop(c); oniStreamDestroy(d); oniStreamDestroy(c); oniDeviceClose(dev); oniShutdown(); break; // no wait
  case 7: oniStreamDestroy(d); oniStreamDestroy(c); oniDeviceClose(dev); break; // destroy running
  case 9: oniStreamStop(d); oniStreamStop(c); oniStreamDestroy(d); oniStreamDestroy(c); oniDeviceClose(dev); usleep(300000); break;
  case 10: oniStreamStop(d); oniStreamStop(c); oniStreamDestroy(d); oniStreamDestroy(c); oniDeviceClose(dev); usleep(300000); oniShutdown(); break;
  case 11: oniStreamStop(d); oniStreamStop(c); usleep(100000); oniStreamDestroy(d); oniStreamDestroy(c); oniDeviceClose(dev); usleep(300000); oniShutdown(); break;
  case 8: { oniStreamStop(d); oniStreamStop(c); usleep(100000); oniStreamDestroy(d); oniStreamDestroy(c); oniDeviceClose(dev);
     // reopen
     oniDeviceOpen("Dummy", &dev); oniDeviceCreateStream(dev, ONI_SENSOR_DEPTH, &d); oniStreamStart(d);
     for (int i = 0; i < 10; i++) { int idx; oniWaitForAnyStream(&d, 1, &idx, 1000); OniFrame* f; oniStreamReadFrame(d, &f); oniFrameRelease(f); }
     oniStreamStop(d); usleep(100000); oniStreamDestroy(d); oniDeviceClose(dev); break; }
  }
  printf("done %d\n", mode); fflush(stdout);
  return 0;
}
