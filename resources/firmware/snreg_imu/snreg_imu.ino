// snreg IMU firmware: Arduino Nano Every + LSM6DSOX (I2C) speaking the snreg serial line protocol
// (docs/design.md, Contracts "IMU serial protocol"), one line per sample at 208 Hz:
//
//   $IMU,<t_us>,<ax>,<ay>,<az>,<gx>,<gy>,<gz>*<CS>
//
// t_us: micros() when the sample was seen (unsigned 32 bit, wraps after 71.6 min); ax..az in g,
// gx..gz in deg/s, both in the sensor frame as printed on the breakout; CS: two hex digits, the
// XOR of the bytes between '$' and '*'. Lines starting with '#' are information; one is printed
// at start and every 5 s, so a host that connects later still learns the rate.
//
// Ranges are the thesis' (§2.4): +-4 g (0.122 mg/LSB) and +-125 deg/s (4.375 mdps/LSB). Values are
// printed from the raw registers with integer arithmetic, six decimals: every LSB exactly, and no
// float formatting (slow, and not in AVR printf). The library's readAcceleration()/readGyroscope()
// are not used: they scale to fixed +-4 g / +-2000 dps whatever the range.
//
// 208 lines/s of up to 81 bytes (16.8 kB/s) do not fit 115200 baud (11.5 kB/s); 230400 (23 kB/s) does,
// with ~25% headroom.

#include <Adafruit_LSM6DSOX.h>
#include <Wire.h>

static const unsigned long BAUD = 230400;
static const long ACCEL_UG_PER_LSB = 122;      // micro-g per LSB at +-4 g
static const long GYRO_UDPS_PER_LSB = 4375;    // micro-deg/s per LSB at +-125 deg/s
static const uint16_t INFO_EVERY = 1040;       // samples between info lines: 5 s at 208 Hz
static const char INFO[] = "# snreg-imu 1 LSM6DSOX odr_hz=208 accel_range_g=4 gyro_range_dps=125";

Adafruit_LSM6DSOX imu;
char line[96];                                 // longest line: 79 characters before \r\n
uint16_t samplesSinceInfo = 0;

// Append ",<value>" with six decimals, value given in millionths: -1000034 -> ",-1.000034".
static char *appendMicro(char *p, long micro) {
  *p++ = ',';
  if (micro < 0) {
    *p++ = '-';
    micro = -micro;
  }
  return p + sprintf(p, "%ld.%06ld", micro / 1000000L, micro % 1000000L);
}

void setup() {
  Serial.begin(BAUD);
  if (!imu.begin_I2C()) {                      // address 0x6A (0x6B if the breakout's DO/AD0 pin is high)
    while (true) {
      Serial.println("# snreg-imu 1 error: no LSM6DSOX at I2C address 0x6A; check the wiring (SDA A4, SCL A5)");
      delay(1000);
    }
  }
  Wire.setClock(400000);                       // fast mode: the 14-byte read takes ~0.4 ms
  imu.setAccelRange(LSM6DS_ACCEL_RANGE_4_G);
  imu.setGyroRange(LSM6DS_GYRO_RANGE_125_DPS);
  imu.setAccelDataRate(LSM6DS_RATE_208_HZ);
  imu.setGyroDataRate(LSM6DS_RATE_208_HZ);
  Serial.println(INFO);
}

void loop() {
  if (!imu.accelerationAvailable() || !imu.gyroscopeAvailable()) {
    return;                                    // poll the data-ready flags of the status register
  }
  unsigned long t_us = micros();
  sensors_event_t accel, gyro, temp;
  imu.getEvent(&accel, &gyro, &temp);          // one burst read; fills rawAccX..rawGyroZ

  char *p = line;
  p += sprintf(p, "$IMU,%lu", t_us);
  p = appendMicro(p, imu.rawAccX * ACCEL_UG_PER_LSB);
  p = appendMicro(p, imu.rawAccY * ACCEL_UG_PER_LSB);
  p = appendMicro(p, imu.rawAccZ * ACCEL_UG_PER_LSB);
  p = appendMicro(p, imu.rawGyroX * GYRO_UDPS_PER_LSB);
  p = appendMicro(p, imu.rawGyroY * GYRO_UDPS_PER_LSB);
  p = appendMicro(p, imu.rawGyroZ * GYRO_UDPS_PER_LSB);
  uint8_t checksum = 0;
  for (const char *q = line + 1; q < p; q++) {
    checksum ^= (uint8_t)*q;
  }
  sprintf(p, "*%02X", checksum);
  Serial.println(line);                        // adds \r\n

  if (++samplesSinceInfo >= INFO_EVERY) {
    samplesSinceInfo = 0;
    Serial.println(INFO);
  }
}
