/* unixcan: the bus folder belongs to its user, and only valid frames leave hilbus_recv.
 *
 * Each check sets UNIXCAN_DIR to a fresh folder under argv[1] (default: the current
 * directory) and tries what the adversarial campaign of issue 16 tried: a symlinked channel
 * folder, "..", a folder of another user, a base others can write to, stray files, and
 * datagrams of every wrong size and length. */
#define _GNU_SOURCE
#include <errno.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <unistd.h>

#include "../check.h"
#include "hilbus.h"


static char root[128];

/* snprintf for paths (vsnprintf: the test's buffers are large enough, truncation is checked) */
static void fmt(char *out, size_t n, const char *f, ...)
{
    va_list ap;
    va_start(ap, f);
    int w = vsnprintf(out, n, f, ap);
    va_end(ap);
    if (w < 0 || (size_t)w >= n) {
        fprintf(stderr, "path too long: %s\n", out);
        exit(2);
    }
}
static int serial;

/* A fresh base folder, set as UNIXCAN_DIR; returns its path. */
static const char *fresh_base(char *out, size_t n)
{
    fmt(out, n, "%s/ucdir-%ld-%d", root, (long)getpid(), serial++);
    CHECK(mkdir(out, 0700) == 0);
    setenv("UNIXCAN_DIR", out, 1);
    return out;
}

static hilbus_t *try_open(const char *channel, char *err, size_t n)
{
    err[0] = '\0';
    return hilbus_open("unixcan", channel, err, n);
}

static mode_t mode_of(const char *path)
{
    struct stat st;
    return lstat(path, &st) == 0 ? (st.st_mode & 07777) : (mode_t)-1;
}

/* A bound socket at path that nobody reads (like a killed node leaves behind). */
static void stale_socket(const char *path)
{
    int s = socket(AF_UNIX, SOCK_DGRAM, 0);
    struct sockaddr_un a;
    memset(&a, 0, sizeof a);
    a.sun_family = AF_UNIX;
    fmt(a.sun_path, sizeof a.sun_path, "%s", path);
    CHECK(bind(s, (struct sockaddr *)&a, sizeof a) == 0);
    close(s);
}

static void test_channel_names(void)
{
    char base[300], err[256];
    fresh_base(base, sizeof base);
    const char *bad[] = {"", ".", "..", "../x", "a/b", "-x", ".hidden", "a b", "a\nb",
                         "0123456789012345678901234567890123456789012345678901234567890123"};
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        hilbus_t *b = try_open(bad[i], err, sizeof err);
        CHECK(b == NULL && strstr(err, "invalid channel name") != NULL);
        if (b) hilbus_close(b);
    }
    const char *good[] = {"vcan0", "t-12_3.x", "A"};
    for (size_t i = 0; i < sizeof good / sizeof good[0]; i++) {
        hilbus_t *b = try_open(good[i], err, sizeof err);
        CHECK(b != NULL);
        if (b) hilbus_close(b);
    }
}

static void test_modes(void)
{
    char base[300], err[256], chan[400], nested[400];
    fresh_base(base, sizeof base);
    /* a base that does not exist yet is created 0700 (and its missing parents) */
    fmt(nested, sizeof nested, "%s/deeper/bus", base);
    setenv("UNIXCAN_DIR", nested, 1);
    hilbus_t *b = try_open("m", err, sizeof err);
    CHECK(b != NULL);
    fmt(chan, sizeof chan, "%s/m", nested);
    CHECK(mode_of(nested) == 0700);
    CHECK(mode_of(chan) == 0700);
    /* the node's socket is 0600 */
    char sock[500];
    fmt(sock, sizeof sock, "%s/%ld-0.sock", chan, (long)getpid());
    int found = 0;
    for (int k = 0; k < 64 && !found; k++) {
        fmt(sock, sizeof sock, "%s/%ld-%d.sock", chan, (long)getpid(), k);
        found = access(sock, F_OK) == 0;
    }
    CHECK(found && mode_of(sock) == 0600);
    if (b) hilbus_close(b);
    /* a channel folder left with a looser mode is tightened: it holds only the bus's sockets */
    CHECK(chmod(chan, 0755) == 0);
    b = try_open("m", err, sizeof err);
    CHECK(b != NULL && mode_of(chan) == 0700);
    if (b) hilbus_close(b);
    /* a base others can write to is refused */
    CHECK(chmod(nested, 0777) == 0);
    b = try_open("m", err, sizeof err);
    CHECK(b == NULL && strstr(err, "writable by other users") != NULL);
    if (b) hilbus_close(b);
    CHECK(chmod(nested, 0755) == 0); /* readable by others is fine: they cannot add entries */
    b = try_open("m", err, sizeof err);
    CHECK(b != NULL);
    if (b) hilbus_close(b);
}

static void test_symlinks_refused(void)
{
    char base[300], err[256], victim[400], link[400], victim_sock[500], victim_file[500];
    fresh_base(base, sizeof base);
    /* somewhere else: a folder with a stale socket and a file that must survive */
    fmt(victim, sizeof victim, "%s-victim", base);
    CHECK(mkdir(victim, 0700) == 0);
    fmt(victim_sock, sizeof victim_sock, "%s/9999-0.sock", victim);
    fmt(victim_file, sizeof victim_file, "%s/keep.sock", victim);
    stale_socket(victim_sock);
    FILE *f = fopen(victim_file, "w");
    CHECK(f != NULL);
    if (f) fclose(f);
    /* the channel folder is a symlink to it */
    fmt(link, sizeof link, "%s/evil", base);
    CHECK(symlink(victim, link) == 0);
    hilbus_t *b = try_open("evil", err, sizeof err);
    CHECK(b == NULL && strstr(err, "symbolic link") != NULL);
    if (b) hilbus_close(b);
    CHECK(access(victim_sock, F_OK) == 0 && access(victim_file, F_OK) == 0);
    /* the base itself a symlink: refused too */
    char base_link[400];
    fmt(base_link, sizeof base_link, "%s-link", base);
    CHECK(symlink(victim, base_link) == 0);
    setenv("UNIXCAN_DIR", base_link, 1);
    b = try_open("x", err, sizeof err);
    CHECK(b == NULL && strstr(err, "symbolic link") != NULL);
    if (b) hilbus_close(b);
    CHECK(access(victim_sock, F_OK) == 0);
}

static void test_only_own_sockets_are_peers(void)
{
    char base[300], err[256], chan[400], path[500];
    fresh_base(base, sizeof base);
    hilbus_t *a = try_open("c", err, sizeof err);
    CHECK(a != NULL);
    if (!a) return;
    fmt(chan, sizeof chan, "%s/c", base);
    /* a regular file named like a socket, and a stale socket of ours */
    fmt(path, sizeof path, "%s/not-a-socket.sock", chan);
    FILE *f = fopen(path, "w");
    CHECK(f != NULL);
    if (f) fclose(f);
    char stale[500];
    fmt(stale, sizeof stale, "%s/4242-7.sock", chan);
    stale_socket(stale);
    hilbus_t *b = try_open("c", err, sizeof err); /* scans on open */
    CHECK(b != NULL);
    struct canfd_frame fr;
    memset(&fr, 0, sizeof fr);
    fr.can_id = 0x12;
    fr.len = 1;
    CHECK(hilbus_send(b, &fr, 0) == 0);
    hilbus_stats_t s;
    hilbus_get_stats(b, &s);
    CHECK(access(path, F_OK) == 0);   /* never removed: not a socket */
    CHECK(access(stale, F_OK) != 0);  /* our own dead node's socket: removed */
    CHECK(s.foreign_entries >= 1 && s.peers_removed == 1 && s.tx_errors == 0);
    if (geteuid() == 0) {
        /* a socket of another user in our folder is not a peer and is never removed */
        char other[500];
        fmt(other, sizeof other, "%s/5151-0.sock", chan);
        stale_socket(other);
        CHECK(chown(other, 65534, 65534) == 0);
        hilbus_t *c = try_open("c", err, sizeof err);
        CHECK(c != NULL);
        CHECK(c != NULL && hilbus_send(c, &fr, 0) == 0);
        CHECK(access(other, F_OK) == 0);
        if (c) hilbus_close(c);
        /* a channel folder of another user is refused */
        CHECK(chown(chan, 65534, 65534) == 0);
        c = try_open("c", err, sizeof err);
        CHECK(c == NULL && strstr(err, "not to this user") != NULL);
        if (c) hilbus_close(c);
        CHECK(chown(chan, 0, 0) == 0);
    }
    hilbus_close(a);
    if (b) hilbus_close(b);
}

/* Datagrams straight into a node's socket: only valid frames come out, the rest is counted. */
static void test_malformed_datagrams(void)
{
    char base[300], err[256], chan[400];
    fresh_base(base, sizeof base);
    hilbus_t *rx = try_open("d", err, sizeof err);
    CHECK(rx != NULL);
    if (!rx) return;
    fmt(chan, sizeof chan, "%s/d", base);
    struct sockaddr_un to;
    memset(&to, 0, sizeof to);
    to.sun_family = AF_UNIX;
    for (int k = 0; k < 64; k++) {
        fmt(to.sun_path, sizeof to.sun_path, "%s/%ld-%d.sock", chan, (long)getpid(), k);
        if (access(to.sun_path, F_OK) == 0) break;
    }
    int s = socket(AF_UNIX, SOCK_DGRAM, 0);
    struct canfd_frame f, got;
    int fd = -1, n_got = 0, last_len = -1;
    /* the receiver queues few datagrams (max_dgram_qlen): read after each one */
#define TAKE()                                                   \
    while (hilbus_recv(rx, &got, &fd, 20000) == 1) {             \
        n_got++;                                                 \
        last_len = got.len;                                      \
        CHECK(got.len <= CANFD_MAX_DLEN);                        \
    }
    unsigned char raw[100];
    memset(raw, 0, sizeof raw);
    int sent_bad = 0;
    /* wrong sizes */
    const size_t sizes[] = {0, 1, 15, 17, 71, 73, 100};
    for (size_t i = 0; i < sizeof sizes / sizeof sizes[0]; i++) {
        CHECK(sendto(s, raw, sizes[i], 0, (struct sockaddr *)&to, sizeof to) == (ssize_t)sizes[i]);
        sent_bad++;
        TAKE();
    }
    /* right sizes, impossible lengths: 255 (FD), 13 (no FD length), 9 (classic) */
    const uint8_t fd_lens[] = {255, 65, 13};
    for (size_t i = 0; i < sizeof fd_lens; i++) {
        memset(&f, 0, sizeof f);
        f.can_id = 0x10;
        f.len = fd_lens[i];
        CHECK(sendto(s, &f, CANFD_MTU, 0, (struct sockaddr *)&to, sizeof to) == CANFD_MTU);
        sent_bad++;
        TAKE();
    }
    memset(&f, 0, sizeof f);
    f.len = 9;
    CHECK(sendto(s, &f, CAN_MTU, 0, (struct sockaddr *)&to, sizeof to) == CAN_MTU);
    sent_bad++;
    TAKE();
    /* and one good frame after them */
    memset(&f, 0, sizeof f);
    f.can_id = 0x42;
    f.len = 64;
    f.data[63] = 0xA5;
    CHECK(sendto(s, &f, CANFD_MTU, 0, (struct sockaddr *)&to, sizeof to) == CANFD_MTU);
    close(s);
    TAKE();
#undef TAKE
    CHECK(n_got == 1 && last_len == 64 && fd == 1);
    hilbus_stats_t st;
    hilbus_get_stats(rx, &st);
    CHECK(st.rx_malformed == (uint64_t)sent_bad);
    if (st.rx_malformed != (uint64_t)sent_bad || n_got != 1) fprintf(stderr, "got %d frames (last len %d), rx_malformed %llu of %d\n", n_got, last_len, (unsigned long long)st.rx_malformed, sent_bad);
    hilbus_close(rx);
}

static void test_default_folder(void)
{
    char err[256], xdg[300], want[400];
    unsetenv("UNIXCAN_DIR");
    unsetenv("UNIXCAN_GROUP");
    fmt(xdg, sizeof xdg, "%s/xdg-%ld", root, (long)getpid());
    CHECK(mkdir(xdg, 0700) == 0);
    setenv("XDG_RUNTIME_DIR", xdg, 1);
    char base[300];
    CHECK(hilbus_unixcan_base(base, sizeof base) == 0);
    fmt(want, sizeof want, "%s/unixcan", xdg);
    CHECK(strcmp(base, want) == 0);
    hilbus_t *b = try_open("dflt", err, sizeof err);
    CHECK(b != NULL && mode_of(want) == 0700);
    if (b) hilbus_close(b);
    unsetenv("XDG_RUNTIME_DIR");
    CHECK(hilbus_unixcan_base(base, sizeof base) == 0);
    fmt(want, sizeof want, "/tmp/unixcan-%lu", (unsigned long)geteuid());
    CHECK(strcmp(base, want) == 0);
}

int main(int argc, char **argv)
{
    /* short paths: a socket address holds 108 bytes */
    fmt(root, sizeof root, "%s/ucd-%ld", argc > 1 ? argv[1] : "/tmp", (long)getpid());
    if (mkdir(root, 0700) != 0) {
        perror(root);
        return 2;
    }
    test_channel_names();
    test_modes();
    test_symlinks_refused();
    test_only_own_sockets_are_peers();
    test_malformed_datagrams();
    test_default_folder();
    char rm[300];
    fmt(rm, sizeof rm, "rm -rf '%s' '%s'-* 2>/dev/null", root, root);
    if (system(rm) != 0) fprintf(stderr, "could not remove %s\n", root);
    return check_report("test_unixcan_dir");
}
