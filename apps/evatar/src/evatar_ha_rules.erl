%% @doc Internal. The pure decisions of high availability: where a standby
%% goes, whether a set of heard nodes is a majority, whether a standby may
%% take over, and which of two instances of one pairing gives way after a
%% partition heals. No processes, no clock: `evatar_cluster' and
%% `evatar_pairing' call these with what they observed (docs/architecture.md,
%% section 8).
-module(evatar_ha_rules).

-export([standby_node/4, majority/2, may_take_over/3, must_fence/3,
         reconcile/2, stalled/3]).

-export_type([instance/0, verdict/0]).

-type instance() :: #{role := active | standby | fenced | starting,
                      epoch := non_neg_integer(),
                      node := node(),
                      pid := pid(),
                      peer => pid() | undefined}.
-type verdict() :: keep | step_down | stop.

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

%% @doc Whether a standby whose active is gone or silent may take over: in a
%% cluster of 3 or more configured nodes only with a majority heard; in a
%% cluster of 2 (or 1) always, since a crash and a partition cannot be told
%% apart there (availability first, docs/architecture.md).
-spec may_take_over(ClusterSize :: pos_integer(), Majority :: boolean(),
                    ActiveAlive :: boolean()) -> boolean().
may_take_over(_Size, _Majority, true) -> false;
may_take_over(Size, _Majority, false) when Size =< 2 -> true;
may_take_over(_Size, Majority, false) -> Majority.

%% @doc Whether an active must fence itself: in a cluster of 3 or more, when
%% it hears neither its standby's node nor a majority within the lease.
-spec must_fence(ClusterSize :: pos_integer(), Majority :: boolean(),
                 StandbyHeard :: boolean()) -> boolean().
must_fence(Size, _Majority, _StandbyHeard) when Size =< 2 -> false;
must_fence(_Size, Majority, StandbyHeard) -> not (Majority orelse StandbyHeard).

%% @doc What instance `Me' does on learning of `Other', another instance of
%% the same pairing on another node. Two actives (fenced counts as active):
%% the lower epoch steps down; on equal epochs the one on the greater node
%% name does. A standby stops when an active with a higher epoch that is not
%% its own active exists. Anything else keeps going.
-spec reconcile(instance(), instance()) -> verdict().
reconcile(#{role := MyRole, epoch := E1, node := N1},
          #{role := OtherRole, epoch := E2, node := N2})
  when (MyRole =:= active orelse MyRole =:= fenced),
       (OtherRole =:= active orelse OtherRole =:= fenced) ->
    case E2 > E1 orelse (E2 =:= E1 andalso N2 < N1) of
        true -> step_down;
        false -> keep
    end;
reconcile(#{role := standby, epoch := E1} = Me,
          #{role := OtherRole, epoch := E2, pid := Pid})
  when OtherRole =:= active; OtherRole =:= fenced ->
    case E2 > E1 andalso maps:get(peer, Me, undefined) =/= Pid of
        true -> stop;
        false -> keep
    end;
reconcile(_Me, _Other) ->
    keep.

%% @doc Whether this node itself was stopped or starved: the last tick came
%% much later than planned. Then silence from the others is not their fault,
%% and they are given a fresh start instead of being suspected.
-spec stalled(LastTickMs :: integer(), NowMs :: integer(), SuspectMs :: pos_integer()) ->
          boolean().
stalled(LastTick, Now, SuspectMs) ->
    Now - LastTick > SuspectMs.
