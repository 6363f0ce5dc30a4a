/*
 * rfh_frames.h -- rfhoming's COBS-framed binary records, for firmware of custom nodes.
 *
 * Portable C99, no allocation, no global state. The wire format is docs/protocol.md section 2:
 *
 *     00 | COBS( header | body | crc16 ) | 00
 *
 * header = version(1) type node_id seq(u16) t_us(u32), every integer little-endian; CRC-16/
 * CCITT-FALSE (poly 0x1021, init 0xFFFF) over header + body, stored little-endian.
 *
 * Encoding: one rfh_encode_<type>() per record type writes the whole frame, both zero
 * delimiters included, into a caller's buffer. It returns the frame's length, or 0 when the
 * buffer is too small or the record breaks a limit (inner frame > RFH_MAX_INNER bytes, a tail
 * longer than 255). Size the buffer with RFH_FRAME_CAP(body bytes) or use RFH_MAX_FRAME.
 *
 * Decoding: rfh_decoder_t holds one frame (RFH_MAX_ENCODED bytes). Feed it bytes; when
 * rfh_decoder_feed() returns RFH_DEC_FRAME, dec->inner holds a frame whose COBS, length
 * (at most RFH_MAX_INNER decoded bytes, the encoder's limit), CRC and version have been checked, and rfh_parse_<type>() reads its body. Tail pointers a parser
 * returns point into dec->inner and stay valid until the next feed.
 */
#ifndef RFH_FRAMES_H
#define RFH_FRAMES_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define RFH_VERSION 1u
#define RFH_HEADER_SIZE 9u
#define RFH_CRC_SIZE 2u
#define RFH_MAX_INNER 1024u
/* COBS adds one code byte per 254 data bytes (rounded up); both delimiters add two. */
#define RFH_MAX_ENCODED (RFH_MAX_INNER + (RFH_MAX_INNER + 253u) / 254u)
#define RFH_FRAME_CAP(body_len) \
    ((RFH_HEADER_SIZE + (body_len) + RFH_CRC_SIZE) + (RFH_HEADER_SIZE + (body_len) + RFH_CRC_SIZE + 253u) / 254u + 2u)
#define RFH_MAX_FRAME (RFH_MAX_ENCODED + 2u)

enum rfh_type {
    RFH_ADV_REPORT = 0x01,
    RFH_RF_FRAME = 0x02,
    RFH_ANTENNA_SET = 0x03,
    RFH_STATUS = 0x10,
    RFH_ODOMETRY = 0x20,
    RFH_VELOCITY_COMMAND = 0x21,
    RFH_RANGE_SCAN = 0x22,        /* version 1: still decoded, no longer sent */
    RFH_RANGE_SCAN_V2 = 0x23,
    RFH_LOG_TEXT = 0x7F,
    RFH_NODE_COMMAND = 0x80
};

typedef struct {
    uint8_t node_id;
    uint16_t seq;  /* per-node record counter: the host counts gaps as lost records */
    uint32_t t_us; /* node clock at reception, wraps every 71.6 min */
} rfh_header_t;

typedef struct { /* 0x01 BLE scan result */
    uint8_t addr[6];      /* LSB first, as on the air */
    uint8_t addr_type;
    uint8_t adv_props;
    int8_t rssi_dbm;      /* 127 = not available */
    int8_t tx_power_dbm;  /* 127 = not available */
    uint8_t channel;      /* 37..39, 255 unknown */
    uint8_t ad_len;
    const uint8_t *ad;
} rfh_adv_report_t;

typedef struct { /* 0x02 AT86RF212 frame on one antenna */
    uint8_t antenna;      /* 0..3 */
    uint8_t channel;
    uint8_t page;
    uint8_t trx_ctrl_2;
    int8_t rssi_base_dbm;
    uint8_t ed;           /* 0..84, 255 = no measurement */
    uint8_t lqi;
    uint8_t rx_status;    /* bit 7 CRC valid, bits 6:4 TRAC status */
    uint16_t emitter_seq;
    uint8_t psdu_len;
    const uint8_t *psdu;
} rfh_rf_frame_t;

typedef struct {
    uint8_t ed;
    uint8_t lqi;
    int16_t dt_us;        /* offset from the header's t_us */
} rfh_antenna_t;

typedef struct { /* 0x03 one emitter frame heard on four antennas */
    uint16_t emitter_seq;
    uint8_t channel;
    uint8_t page;
    int8_t rssi_base_dbm;
    uint8_t valid_mask;   /* bit i = antenna i heard the frame */
    rfh_antenna_t antennas[4];
} rfh_antenna_set_t;

typedef struct { /* 0x10 node status, 1 Hz */
    uint8_t device_kind;  /* 1 ESP32 BLE scanner, 2 AT86RF212 node, 3 robot base */
    uint8_t fw_major;
    uint8_t fw_minor;
    uint8_t fw_patch;
    uint32_t uptime_ms;
    uint16_t tx_dropped;
    uint16_t rx_errors;
} rfh_status_t;

typedef struct { /* 0x20 base -> host */
    int32_t x_mm;
    int32_t y_mm;
    int32_t theta_urad;   /* within +-pi * 1e6 */
    int16_t v_mm_s;
    int16_t w_mrad_s;
    uint8_t flags;        /* bit 0 watchdog stop, bit 1 contact, bit 2 motors enabled */
} rfh_odometry_t;

typedef struct { /* 0x21 host -> base */
    int16_t v_mm_s;
    int16_t w_mrad_s;
    uint16_t timeout_ms;  /* the base stops when it expires */
} rfh_velocity_command_t;

typedef struct { /* 0x22 base -> host */
    int16_t angle_min_mrad;
    int16_t angle_inc_mrad;
    uint8_t count;
    const uint16_t *ranges_mm; /* encoding reads host order; a parser gives raw LE bytes, see below */
} rfh_range_scan_t;

typedef struct { /* 0x23 base -> host: the exact geometry */
    int32_t angle_min_urad;    /* the first beam, counter-clockwise from ahead */
    int32_t angle_max_urad;    /* the last beam; beams evenly spaced between */
    uint16_t range_max_mm;     /* the sensor's maximum range */
    uint8_t count;
    const uint16_t *ranges_mm; /* as in rfh_range_scan_t */
} rfh_range_scan_v2_t;

typedef struct { /* 0x7F firmware log line, UTF-8 (the encoder refuses, the parser rejects other bytes) */
    const char *text;
    size_t len;
} rfh_log_text_t;

typedef struct { /* 0x80 host -> node */
    uint8_t command;      /* 1 set channel/page (args: channel, page), 2 start, 3 stop, 4 status */
    const uint8_t *args;
    size_t args_len;
} rfh_node_command_t;

uint16_t rfh_crc16(const uint8_t *data, size_t len);

size_t rfh_encode_adv_report(uint8_t *out, size_t cap, const rfh_header_t *h, const rfh_adv_report_t *r);
size_t rfh_encode_rf_frame(uint8_t *out, size_t cap, const rfh_header_t *h, const rfh_rf_frame_t *r);
size_t rfh_encode_antenna_set(uint8_t *out, size_t cap, const rfh_header_t *h, const rfh_antenna_set_t *r);
size_t rfh_encode_status(uint8_t *out, size_t cap, const rfh_header_t *h, const rfh_status_t *r);
size_t rfh_encode_odometry(uint8_t *out, size_t cap, const rfh_header_t *h, const rfh_odometry_t *r);
size_t rfh_encode_velocity_command(uint8_t *out, size_t cap, const rfh_header_t *h,
                                   const rfh_velocity_command_t *r);
size_t rfh_encode_range_scan(uint8_t *out, size_t cap, const rfh_header_t *h, const rfh_range_scan_t *r);
size_t rfh_encode_range_scan_v2(uint8_t *out, size_t cap, const rfh_header_t *h, const rfh_range_scan_v2_t *r);
size_t rfh_encode_log_text(uint8_t *out, size_t cap, const rfh_header_t *h, const rfh_log_text_t *r);
size_t rfh_encode_node_command(uint8_t *out, size_t cap, const rfh_header_t *h, const rfh_node_command_t *r);

/* ---- decoding ---------------------------------------------------------------------------- */

typedef enum {
    RFH_DEC_NONE = 0,    /* byte taken, no frame ended */
    RFH_DEC_FRAME = 1,   /* dec->inner holds a checked frame */
    RFH_DEC_DROP = 2     /* a frame ended and was dropped; dec->drop says why */
} rfh_dec_result_t;

typedef enum {
    RFH_DROP_NONE = 0, RFH_DROP_OVERSIZE, RFH_DROP_COBS, RFH_DROP_SHORT, RFH_DROP_CRC,
    RFH_DROP_VERSION
} rfh_drop_t;

typedef struct {
    uint8_t buf[RFH_MAX_ENCODED];  /* the frame being received, still COBS-encoded */
    size_t len;
    int discarding;                /* an oversize frame: skip to the next zero */
    uint8_t inner[RFH_MAX_INNER];  /* the last good frame: header | body | crc */
    size_t inner_len;
    uint8_t type;
    rfh_header_t header;
    rfh_drop_t drop;
    uint32_t frames, drops;        /* counters, wrap */
} rfh_decoder_t;

void rfh_decoder_init(rfh_decoder_t *dec);
rfh_dec_result_t rfh_decoder_feed(rfh_decoder_t *dec, uint8_t byte);
/* The body of the last good frame and its length (inner minus header and CRC). */
const uint8_t *rfh_decoder_body(const rfh_decoder_t *dec, size_t *len);

/* Whether b[0..len) is well-formed UTF-8, as the host's decoder requires of a log_text. */
int rfh_utf8_valid(const uint8_t *b, size_t len);

/* Parsers return 1 when `len` fits the type, 0 otherwise (the host drops those as "length";
 * a log_text that is not UTF-8 as "text").
 * rfh_parse_range_scan() and rfh_parse_range_scan_v2() set ranges_mm to NULL and gives the little-endian bytes in
 * *ranges_le (2 * count bytes), since the body need not be aligned for uint16_t. */
int rfh_parse_adv_report(const uint8_t *body, size_t len, rfh_adv_report_t *r);
int rfh_parse_rf_frame(const uint8_t *body, size_t len, rfh_rf_frame_t *r);
int rfh_parse_antenna_set(const uint8_t *body, size_t len, rfh_antenna_set_t *r);
int rfh_parse_status(const uint8_t *body, size_t len, rfh_status_t *r);
int rfh_parse_odometry(const uint8_t *body, size_t len, rfh_odometry_t *r);
int rfh_parse_velocity_command(const uint8_t *body, size_t len, rfh_velocity_command_t *r);
int rfh_parse_range_scan(const uint8_t *body, size_t len, rfh_range_scan_t *r, const uint8_t **ranges_le);
int rfh_parse_range_scan_v2(const uint8_t *body, size_t len, rfh_range_scan_v2_t *r, const uint8_t **ranges_le);
int rfh_parse_log_text(const uint8_t *body, size_t len, rfh_log_text_t *r);
int rfh_parse_node_command(const uint8_t *body, size_t len, rfh_node_command_t *r);

#ifdef __cplusplus
}
#endif

#endif /* RFH_FRAMES_H */
