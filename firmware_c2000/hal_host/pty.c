/* pty.c - pseudo-terminal for the SCI console (see pty.h). */
#define _GNU_SOURCE /* posix_openpt, grantpt, unlockpt, ptsname_r, cfmakeraw, cfsetspeed */
#include "pty.h"

#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <unistd.h>

/* raw, 115200 baud, 8 data bits, no parity, 1 stop bit, receiver on, no modem control */
static int configure_line(int fd)
{
    struct termios t;
    if (tcgetattr(fd, &t) != 0) {
        return -1;
    }
    cfmakeraw(&t);
    t.c_cflag &= ~(tcflag_t)(CSIZE | PARENB | CSTOPB | CRTSCTS);
    t.c_cflag |= CS8 | CREAD | CLOCAL;
    t.c_iflag &= ~(tcflag_t)(IXON | IXOFF | IXANY);
    t.c_lflag &= ~(tcflag_t)(ECHO | ECHONL | ICANON | ISIG | IEXTEN);
    t.c_cc[VMIN] = 1;
    t.c_cc[VTIME] = 0;
    if (cfsetispeed(&t, B115200) != 0 || cfsetospeed(&t, B115200) != 0) {
        return -1;
    }
    return tcsetattr(fd, TCSANOW, &t);
}

int fwh_pty_open(fwh_pty_t *p, const char *link, char *err, size_t errlen)
{
    memset(p, 0, sizeof(*p));
    p->master = posix_openpt(O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
    if (p->master < 0) {
        snprintf(err, errlen, "posix_openpt: %s", strerror(errno));
        return -1;
    }
    if (grantpt(p->master) != 0 || unlockpt(p->master) != 0 ||
        ptsname_r(p->master, p->slave_path, sizeof(p->slave_path)) != 0) {
        snprintf(err, errlen, "pseudo-terminal set-up: %s", strerror(errno));
        close(p->master);
        p->master = -1;
        return -1;
    }
    if (configure_line(p->master) != 0) {
        snprintf(err, errlen, "termios on %s: %s", p->slave_path, strerror(errno));
        close(p->master);
        p->master = -1;
        return -1;
    }
    if (link != NULL && link[0] != '\0') {
        char tmp[FWH_PTY_PATH_MAX + 32];
        if (strlen(link) >= sizeof(p->link)) {
            snprintf(err, errlen, "--pty-link: path too long");
            close(p->master);
            p->master = -1;
            return -1;
        }
        snprintf(tmp, sizeof(tmp), "%s.tmp.%ld", link, (long)getpid());
        unlink(tmp);
        if (symlink(p->slave_path, tmp) != 0 || rename(tmp, link) != 0) {
            snprintf(err, errlen, "--pty-link %s: %s", link, strerror(errno));
            unlink(tmp);
            close(p->master);
            p->master = -1;
            return -1;
        }
        snprintf(p->link, sizeof(p->link), "%s", link);
    }
    return 0;
}

void fwh_pty_close(fwh_pty_t *p)
{
    if (p->link[0] != '\0') {
        char target[sizeof(p->slave_path)];
        ssize_t n = readlink(p->link, target, sizeof(target) - 1);
        if (n > 0) {
            target[n] = '\0';
            if (strcmp(target, p->slave_path) == 0) {
                unlink(p->link);
            }
        }
        p->link[0] = '\0';
    }
    if (p->master >= 0) {
        close(p->master);
        p->master = -1;
    }
}

int fwh_pty_read(fwh_pty_t *p, char *buf, size_t len)
{
    ssize_t n;
    do {
        n = read(p->master, buf, len);
    } while (n < 0 && errno == EINTR);
    if (n > 0) {
        return (int)n;
    }
    if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) {
        return 0;
    }
    return -1; /* EIO: no client has the slave open */
}

void fwh_pty_flush(fwh_pty_t *p)
{
    while (p->out_len > 0) {
        ssize_t n = write(p->master, p->out, p->out_len);
        if (n < 0) {
            if (errno == EINTR) {
                continue;
            }
            if (errno != EAGAIN && errno != EWOULDBLOCK) {
                fwh_pty_discard(p); /* EIO: nobody is listening */
            }
            return;
        }
        memmove(p->out, p->out + n, p->out_len - (size_t)n);
        p->out_len -= (size_t)n;
    }
}

void fwh_pty_write(fwh_pty_t *p, const char *data, size_t len)
{
    size_t room = sizeof(p->out) - p->out_len;
    if (len > room) {
        p->out_dropped += len - room;
        len = room;
    }
    memcpy(p->out + p->out_len, data, len);
    p->out_len += len;
    fwh_pty_flush(p);
}

void fwh_pty_discard(fwh_pty_t *p)
{
    p->out_dropped += p->out_len;
    p->out_len = 0;
}
