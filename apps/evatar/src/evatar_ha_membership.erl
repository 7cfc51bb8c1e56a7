%% @doc Internal. The pure decisions of cluster membership: where a standby
%% goes, whether a set of heard nodes is a majority, whether this node was
%% paused itself and how much of the peers' silence that explains, and
%% whether the timings hang together. No processes, no clock:
%% `evatar_cluster' calls these with what it observed. The decisions about
%% one pairing's instances (votes, registrations, fencing, reconciling two
%% instances) are in `evatar_ha_core' (docs/ha-design.md).
-module(evatar_ha_membership).

-export([standby_node/4, majority/2, stalled/3, stall_ms/2, own_pause/3, discount/3,
         check_timings/1]).

%% @doc The node for a standby of a pairing active on `Self': `Preferred'
%% when it is alive, else the first alive node after `Self' in the sorted
%% ring of `Configured'. `none' when no other node is alive.
-spec standby_node([node()], node(), [node()], node() | undefined) -> node() | none.
standby_node(Configured, Self, Alive, Preferred) ->
    Candidates = [N || N <- Alive, N =/= Self, lists:member(N, Configured)],
    case lists:member(Preferred, Candidates) of
        true ->
            Preferred;
        false ->
            Ring = lists:usort(Configured),
            {Before, After} = lists:splitwith(fun(N) -> N =< Self end, Ring),
            case [N || N <- After ++ Before, lists:member(N, Candidates)] of
                [N | _] -> N;
                [] -> none
            end
    end.

%% @doc Whether `Heard' (nodes heard recently, this one included) is a
%% strict majority of the `Configured' nodes.
-spec majority([node()], [node()]) -> boolean().
majority(Configured, Heard) ->
    Votes = length([N || N <- lists:usort(Heard), lists:member(N, Configured)]),
    Votes * 2 > length(lists:usort(Configured)).

%% @doc Whether this node itself was stopped or starved: the last tick came
%% more than `StallMs' ({@link stall_ms/2}) after the one before. Then
%% silence from the others is not their fault, and they are given a fresh
%% start instead of being suspected; its actives ask the cluster again.
-spec stalled(LastTickMs :: integer(), NowMs :: integer(), StallMs :: pos_integer()) ->
          boolean().
stalled(LastTick, Now, StallMs) ->
    Now - LastTick > StallMs.

%% @doc How long a gap between two ticks counts as a stall: `lease_ms' +
%% `heartbeat_ms', which check_timings/1 keeps at most `suspect_ms'. The
%% peers suspect this node after `suspect_ms' of silence on their clocks;
%% this node measures its pause on its own. Counted against suspect_ms, a
%% pause the peers measured as just over it (their clocks a little faster)
%% would go unnoticed here, and a standby could take over while this
%% node's active served on without asking anyone. Counted against
%% lease + heartbeat, every pause a peer could have suspected is noticed as
%% long as this node's clock runs at no less than (lease + heartbeat) /
%% suspect of theirs: the same bound the lease itself needs (docs/ha.md
%% section 6, "Clock drift").
-spec stall_ms(HeartbeatMs :: pos_integer(), LeaseMs :: pos_integer()) -> pos_integer().
stall_ms(HeartbeatMs, LeaseMs) ->
    LeaseMs + HeartbeatMs.

%% @doc How long this node was itself paused before a tick: how much later
%% than planned (`HeartbeatMs' after the last one) the tick came. The
%% peers' silence during that time says nothing about them ({@link
%% discount/3}).
-spec own_pause(LastTickMs :: integer(), NowMs :: integer(), HeartbeatMs :: pos_integer()) ->
          non_neg_integer().
own_pause(LastTick, Now, HeartbeatMs) ->
    max(0, Now - LastTick - HeartbeatMs).

%% @doc When a peer counts as last heard once this node's own pause is
%% taken out: a peer silent for 40 ms before a pause of 300 ms is silent
%% for 40 ms after it, not 340 ms, so neither its suspicion nor this
%% node's lease counts time in which this node could not hear anything.
%% A peer silent before the pause stays as silent. Never later than `Now'.
-spec discount(HeardAtMs :: integer(), PausedMs :: non_neg_integer(), NowMs :: integer()) ->
          integer().
discount(HeardAt, PausedMs, Now) ->
    min(Now, HeardAt + PausedMs).

%% @doc Whether the high-availability timings hang together: positive
%% integers with `lease_ms + heartbeat_ms =< suspect_ms', so an active cut
%% off from the majority has fenced before any node stops hearing it for
%% `suspect_ms' and votes it away (docs/ha-design.md). The
%% error names the setting and says what is wrong.
-spec check_timings(#{heartbeat_ms := term(), suspect_ms := term(), lease_ms := term()}) ->
          ok | {error, {bad_ha_timing, atom(), term(), string()}}.
check_timings(#{heartbeat_ms := Hb, suspect_ms := Suspect, lease_ms := Lease} = T) ->
    case [K || K <- [heartbeat_ms, suspect_ms, lease_ms],
               not (is_integer(maps:get(K, T)) andalso maps:get(K, T) > 0)] of
        [K | _] ->
            {error, {bad_ha_timing, K, maps:get(K, T), "must be a positive integer (ms)"}};
        [] when Lease + Hb > Suspect ->
            {error, {bad_ha_timing, suspect_ms, Suspect,
                     lists:flatten(io_lib:format("must be at least lease_ms + heartbeat_ms "
                                                 "(~b + ~b)", [Lease, Hb]))}};
        [] ->
            ok
    end.
