"""The classroom: a lobby that hands each student a seat (an own lab in an own `torquelab serve`
process, reached only through the lobby) and the teacher a live view of every seat.

`seat` runs inside a seat's process (its status out, the teacher's commands in, over the pipes the
lobby holds); `seats` starts, watches and reclaims the seat processes; `lobby` is the one port a
class opens (the pages, the cookie, the websocket proxy, the teacher's view); `pages` holds the HTML.
"""
