// motor_card.ino - reference card firmware for motor_id (serial protocol: docs/protocol.md).
//
// Streams samples (card time, voltage, speed, current) and obeys the host's commands
// (set_voltage, start_profile paper_steps / bipolar_steps, stop, set_period, ping) with
// the protocol core in motor_card.h: copy ../motor_card.h next to this file first
// (see ../README.md). Reference target: ATmega328P boards (Uno, Nano) at 16 MHz;
// other boards build too but need a sampling timer (see start_sampling_timer()).
//
// Everything marked "USER HARDWARE" is a placeholder for your encoder, current sensor
// and H-bridge: check every value before powering a motor.

#include "motor_card.h"

// ---- USER HARDWARE: pins ------------------------------------------------------------
const uint8_t PIN_ENC_A = 2;        // quadrature encoder channel A (interrupt pin)
const uint8_t PIN_ENC_B = 3;        // quadrature encoder channel B (interrupt pin)
const uint8_t PIN_PWM = 9;          // H-bridge PWM input (Timer1 on the Uno: keep it free)
const uint8_t PIN_DIR = 8;          // H-bridge direction input
const uint8_t PIN_CURRENT = A0;     // current-sense amplifier output

// ---- USER HARDWARE: scaling ---------------------------------------------------------
const float COUNTS_PER_REV = 2048.0f;   // encoder counts per shaft revolution (x4 decoding)
const float SUPPLY_VOLTS = 12.0f;       // H-bridge supply [V]: the voltage at 100 % duty
const float ADC_VREF = 5.0f;            // ADC reference [V]
const float ADC_COUNTS = 1024.0f;       // ADC full scale
const float CURRENT_ZERO_V = 2.5f;      // sensor output at 0 A [V]
const float AMPS_PER_VOLT = 10.0f;      // sensor gain [A/V] (e.g. 100 mV/A)
const bool WITH_CURRENT = true;         // false: no current sensor, frames carry none

// ---- card settings ------------------------------------------------------------------
const uint32_t BAUD = 115200;           // a 34-byte frame takes 3 ms: period >= 5 ms here
const uint32_t PERIOD_US = 10000;       // initial sample period [us] (host: set_period)
const double V_LIMIT = 12.0;            // largest |voltage| / |amplitude| accepted [V]
const uint32_t WATCHDOG_US = 500000;    // 0 V after 0.5 s without a command, profiles too
                                        // (the driver pings; 0: off, never on a motor)
const uint32_t TICK_US = 100;           // sampling timer tick [us]: periods are multiples

const float TWO_PI_F = 6.28318530718f;

mc_card card;

volatile int32_t enc_count = 0;         // encoder position [counts]
volatile uint8_t enc_state = 0;
volatile uint32_t tick_micros = 0;      // latched by the sampling timer
volatile int32_t tick_count = 0;
volatile bool tick_ready = false;

// ---- USER HARDWARE: encoder (x4 quadrature decoding on both edges of A and B) --------
void encoder_isr()
{
    // index: previous AB, current AB -> -1, 0, +1 (0 for invalid double steps)
    static const int8_t step[16] = {0, -1, 1, 0, 1, 0, 0, -1, -1, 0, 0, 1, 0, 1, -1, 0};
    uint8_t ab = (uint8_t)((digitalRead(PIN_ENC_A) << 1) | digitalRead(PIN_ENC_B));
    enc_state = (uint8_t)(((enc_state << 2) | ab) & 0x0F);
    enc_count += step[enc_state];
}

// The timer latches the time and the position together, so the speed belongs to the
// time stamp whatever loop() is doing.
void latch_sample()
{
    tick_micros = micros();
    tick_count = enc_count;
    tick_ready = true;
}

#if defined(__AVR_ATmega328P__) || defined(__AVR_ATmega168__)
ISR(TIMER2_COMPA_vect)
{
    latch_sample();
}

void start_sampling_timer()
{
    // Timer2, CTC, clk/8: one compare match every TICK_US (analogWrite on 3 and 11 is lost)
    noInterrupts();
    TCCR2A = _BV(WGM21);
    TCCR2B = _BV(CS21);
    OCR2A = (uint8_t)(F_CPU / 8UL / 1000000UL * TICK_US - 1UL);
    TCNT2 = 0;
    TIMSK2 = _BV(OCIE2A);
    interrupts();
}
#else
// USER HARDWARE: on other boards call latch_sample() from a TICK_US hardware timer
// interrupt (IntervalTimer on Teensy, hw_timer on ESP32, TC on SAMD). Until then
// loop() polls, which adds its own latency to the time stamps.
void start_sampling_timer()
{
}
#endif

// ---- USER HARDWARE: measurements ------------------------------------------------------
float read_current()
{
    float volts = (float)analogRead(PIN_CURRENT) * (ADC_VREF / ADC_COUNTS);
    return (volts - CURRENT_ZERO_V) * AMPS_PER_VOLT;
}

// ---- USER HARDWARE: H-bridge -----------------------------------------------------------
void apply_voltage(float u)
{
    float duty = fabs(u) / SUPPLY_VOLTS * 255.0f;
    digitalWrite(PIN_DIR, u < 0.0f ? HIGH : LOW);
    analogWrite(PIN_PWM, duty >= 255.0f ? 255 : (int)(duty + 0.5f));
}

void setup()
{
    pinMode(PIN_PWM, OUTPUT);
    pinMode(PIN_DIR, OUTPUT);
    apply_voltage(0.0f);                    // motor off before anything else
    pinMode(PIN_ENC_A, INPUT_PULLUP);
    pinMode(PIN_ENC_B, INPUT_PULLUP);
    attachInterrupt(digitalPinToInterrupt(PIN_ENC_A), encoder_isr, CHANGE);
    attachInterrupt(digitalPinToInterrupt(PIN_ENC_B), encoder_isr, CHANGE);
    Serial.begin(BAUD);

    mc_config cfg = mc_default_config();
    cfg.period_us = PERIOD_US;
    cfg.v_limit = V_LIMIT < SUPPLY_VOLTS ? V_LIMIT : SUPPLY_VOLTS;
    cfg.watchdog_us = WATCHDOG_US;
    cfg.with_current = WITH_CURRENT;
    mc_card_init(&card, &cfg, micros());
    start_sampling_timer();
}

void serve_commands()
{
    uint8_t reply[MC_REPLY_FRAME];
    size_t n;
    while (Serial.available() > 0) {
        mc_card_rx_byte(&card, (uint8_t)Serial.read());
        while ((n = mc_card_poll_rx(&card, micros(), reply)) > 0) {
            Serial.write(reply, n);
        }
    }
}

void loop()
{
    static int32_t last_count = 0;
    static uint64_t last_t = 0;
    uint32_t now_micros;
    int32_t count;
    uint64_t t_us;

    serve_commands();
#if defined(__AVR_ATmega328P__) || defined(__AVR_ATmega168__)
    if (!tick_ready) {
        return;
    }
    noInterrupts();
    now_micros = tick_micros;
    count = tick_count;
    tick_ready = false;
    interrupts();
#else
    now_micros = micros();
    noInterrupts();
    count = enc_count;
    interrupts();
#endif
    if (!mc_card_due(&card, now_micros, &t_us)) {
        return;
    }
    // Mean speed over the last period (a difference quotient lags by half a period;
    // replace with your speed estimate if you have a better one).
    float speed = 0.0f;
    if (t_us > last_t) {
        int32_t counts = (int32_t)((uint32_t)count - (uint32_t)last_count);
        speed = (float)counts * (TWO_PI_F / COUNTS_PER_REV) / ((float)(t_us - last_t) * 1e-6f);
    }
    last_count = count;
    last_t = t_us;
    float current = WITH_CURRENT ? read_current() : 0.0f;

    uint8_t frame[MC_SAMPLE_FRAME_MAX];
    float u;
    size_t n = mc_card_sample(&card, t_us, speed, current, frame, &u);
    apply_voltage(u);                       // held until the next sample
    if (n > 0) {
        Serial.write(frame, n);
    }
}
